r'''The benchmark scripts: --help, one tiny case each, the shape of their JSON document

Each script runs in a subprocess as a user runs it (python benchmarks/X.py), on
one core (NUMBA_NUM_THREADS=1), writing into a temporary --out-dir. The figures
themselves are not checked: they depend on the machine and its load.
'''

import importlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
BENCH = REPO / "benchmarks"
SCRIPTS = ("accuracy", "bench_render", "bench_stages", "bench_campaign", "legacy_signature",
           "bench_raycast_area", "bench_corners", "bench_models", "bench_command_protocol",
           "renderer_gate", "speed", "bench_photometric", "bench_dot_window")
ENV = dict(os.environ, NUMBA_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")

TINY_CAMPAIGN = '''
name = "tiny"
cameras = [17]
models = ["CAHV"]
targets = ["dots"]
[poses]
n = 6
seed = 0
[[renderer]]
name = "raycast"
spp = 1
adaptive = true
[[calibrator]]
name = "jpl"
'''


def run(script, *args, check=True):
    r = subprocess.run([sys.executable, str(BENCH / f"{script}.py"), *map(str, args)],
                       capture_output=True, text=True, cwd=REPO, env=ENV, timeout=600)
    if check:
        assert r.returncode == 0, r.stderr[-3000:]
    return r


def documents(out_dir):
    return sorted(Path(out_dir).glob("*.json"))


def check_document(path, script, part=None):
    doc = json.loads(Path(path).read_text())
    assert doc["schema"] == 1 and doc["kind"] == "camval-benchmark"
    assert doc["script"] == script and doc["part"] == part
    name = f"{script}-{part}" if part else script
    assert re.fullmatch(rf"\d{{8}}T\d{{6}}Z-{name}(-\d+)?\.json", Path(path).name), path
    assert set(doc["commit"]) == {"commit", "dirty"}
    assert {"hostname", "cpus", "python"} <= set(doc["machine"])
    assert doc["environment"]["numba_threads"] == 1
    assert doc["environment"]["peak_rss_bytes"] > 0
    assert doc["records"]
    for name, rec in doc["records"].items():
        assert rec["fullname"] == name
        assert rec["status"] in ("ok", "failed", "not-applicable", "unavailable",
                                 "not-visible"), (name, rec)
    return doc


@pytest.mark.parametrize("script", SCRIPTS)
def test_help_is_the_docstring(script):
    r = run(script, "--help")
    first = (BENCH / f"{script}.py").read_text().split("'''")[1].splitlines()[0]
    assert first in r.stdout


@pytest.fixture(scope="module")
def common():
    sys.path.insert(0, str(BENCH))
    try:
        yield importlib.import_module("common")
    finally:
        sys.path.remove(str(BENCH))


@pytest.mark.parametrize("script", ("bench_render", "bench_stages"))
def test_every_part_has_help(common, script):
    mod = importlib.import_module(script)
    for name, (fn, _) in mod.PARTS.items():
        ap = common.parser(mod.__doc__, mod.PARTS)
        with pytest.raises(SystemExit) as e:
            ap.parse_args([name, "--help"])
        assert e.value.code == 0, name
        assert fn.__doc__.splitlines()[0]


def test_help_imports_nothing_heavy(common):
    # --help must be instant: the scripts import numba, the renderers and the
    # harness's stages only once the arguments are parsed
    code = ("import os, runpy, sys\n"
            "sys.argv = [sys.argv[1], '--help']\n"
            "sys.path.insert(0, os.path.dirname(sys.argv[0]))\n"
            "try:\n    runpy.run_path(sys.argv[0], run_name='__main__')\n"
            "except SystemExit:\n    pass\n"
            "print(sorted(m for m in ('numba', 'harness.runner', 'renderers', 'mrcal')"
            " if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code, str(BENCH / "bench_render.py")],
                       capture_output=True, text=True, cwd=REPO, env=ENV, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().splitlines()[-1] == "[]"


def test_bench_corners_fits_what_the_calibrators_fit(common):
    # bench_corners' "fitted" column takes off what the calibrators' bias step takes off
    # under the true model and pose: the window's curvature bias on window corners, a
    # tag-edge corner's span bias from its own record (none without one), nothing on a
    # corner of another detector
    from types import SimpleNamespace

    from synthetic import synthetic_poses
    from test_corner_model_bias import TARGET, _fisheye, _spans

    from harness.calibrators.bias import corner_bias, tag_edges_bias
    from targets.detection import CORNER_WINDOW, TAG_EDGES
    bench = importlib.import_module("bench_corners")
    truth = _fisheye()
    Rt = synthetic_poses(truth, TARGET)[1]
    n = TARGET.Npoints
    model = np.where(np.arange(n) < n // 2, CORNER_WINDOW, TAG_EDGES)
    spans = _spans(1)[0]
    spans[-8:] = np.nan                        # tag-edge corners without a record
    det = SimpleNamespace(corner_model=model, corner_blur_px=0.7, corner_spans=spans)
    b = bench.calibrator_bias(det, truth, TARGET, Rt)
    window = corner_bias(truth, TARGET, Rt, TARGET.points())
    edges = tag_edges_bias(truth, Rt, TARGET.points(), spans)
    w, e = model == CORNER_WINDOW, (model == TAG_EDGES) & np.isfinite(spans).all((1, 2))
    assert np.abs(b[w] - window[w]).max() < 1e-12
    assert np.abs(b[e] - edges[e]).max() < 1e-12
    assert np.abs(edges[e]).max() > 1e-4       # the record's bias is there to take off
    assert (b[-8:] == 0.0).all()
    other = SimpleNamespace(corner_model=np.full(n, "pupil_apriltags"), corner_blur_px=0.0,
                            corner_spans=None)
    assert (bench.calibrator_bias(other, truth, TARGET, Rt) == 0.0).all()


def test_accuracy_twice_never_overwrites(tmp_path):
    for _ in range(2):
        run("accuracy", "--cameras", "17", "--step", "64", "--out-dir", tmp_path)
    paths = documents(tmp_path)
    assert len(paths) == 2
    for p in paths:
        doc = check_document(p, "accuracy")
        assert set(doc["records"]) == {"accuracy/17", "accuracy/all"}
        assert doc["records"]["accuracy/17"]["round_trip_max_px"] < 1e-9


def test_same_stamp_gets_a_new_name(common, tmp_path, monkeypatch):
    monkeypatch.setattr(common, "utc_stamp", lambda: "20260101T000000Z")
    names = []
    for _ in range(3):
        out = common.Results("demo", out_dir=tmp_path)
        out.add("a/b", x=1.0)
        names.append(out.write().name)
    assert names == ["20260101T000000Z-demo.json", "20260101T000000Z-demo-2.json",
                     "20260101T000000Z-demo-3.json"]
    with pytest.raises(ValueError, match="added twice"):
        out.add("a/b")


def test_timed(common):
    calls = []
    t = common.timed(lambda: calls.append(1) or len(calls), repeats=3, warmup=2)
    assert len(calls) == 5 and t["result"] == 5
    for k in ("cpu_s", "wall_s"):
        assert len(t[k]["values"]) == 3
        assert t[k]["min"] <= t[k]["median"] <= max(t[k]["values"])


def test_bench_render_raycast_tiny(tmp_path):
    run("bench_render", "raycast", "--cameras", "17", "--K", "1", "--speed-cameras", "17",
        "--repeats", "1", "--skip-large", "--out-dir", tmp_path)
    [path] = documents(tmp_path)
    doc = check_document(path, "bench_render", "raycast")
    assert set(doc["records"]) == {"raycast/accuracy/17/K=1", "raycast/accuracy/all/K=1",
                                   "raycast/speed/17/K=16"}
    speed = doc["records"]["raycast/speed/17/K=16"]
    assert len(speed["wall_s"]["values"]) == 6 and speed["cpu_s"]["min"] > 0


def test_bench_stages_poses_tiny(tmp_path):
    run("bench_stages", "poses", "--campaign", "quick", "--repeats", "1", "--warmup", "0",
        "--out-dir", tmp_path)
    [path] = documents(tmp_path)
    doc = check_document(path, "bench_stages", "poses")
    assert doc["records"]["poses/all"]["jobs"] == len(doc["records"]) - 1


def test_bench_campaign_tiny(tmp_path):
    campaign = tmp_path / "tiny.toml"
    campaign.write_text(TINY_CAMPAIGN)
    out = tmp_path / "results"
    run("bench_campaign", "--campaigns", campaign, "-j", "1", "--repeats", "1",
        "--out-dir", out)
    [path] = documents(out)
    doc = check_document(path, "bench_campaign")
    rec = doc["records"]["campaign/tiny/repeat-1"]
    assert rec["status"] == "ok", rec
    assert rec["records"] == 1 and rec["images"] == 6 and rec["statuses"] == {"ok": 1}
    assert {"poses", "render", "detect", "compare", "calibrate:jpl", "cpu:poses",
            "cpu:render_detect", "cpu:calibrate_compare"} == set(rec["stage_seconds"])
    assert rec["peak_rss_bytes"] > 0
    assert len(doc["records"]["campaign/tiny/repeated"]["wall_s"]["values"]) == 1


def test_bench_photometric_tiny(tmp_path):
    # hazcam 17 through an exposure 30% short: judged by the default gate, it passes
    out = tmp_path / "results"
    run("bench_photometric", tmp_path / "runs", "--cameras", "17", "--stages", "gain",
        "-j", "1", "--out-dir", out)
    [path] = documents(out)
    doc = check_document(path, "bench_photometric")
    [rec] = doc["records"].values()
    assert rec["fullname"] == "gain/0/17/jpl[CAHVORE]"
    assert rec["verdict"] == "pass" and rec["worst_z"] < 6, rec
    assert doc["z_statistics"]["gain/jpl"]["n"] > 0


def test_bench_dot_window_tiny(tmp_path):
    # hazcam 17, 2 poses through the realistic profile: the detector's window against the
    # sharp 2 px and blur_window's 3 px (the figures are a render's and a seeded noise's,
    # not the machine's: its choice is the better one, within 10 % of it where it is not)
    out = tmp_path / "results"
    run("bench_dot_window", "--cameras", "17", "--profiles", "b0.7n20000", "--windows", "2,3",
        "--poses", "2", "--out-dir", out)
    [path] = documents(out)
    doc = check_document(path, "bench_dot_window")
    rec = doc["records"]["17/b0.7n20000"]
    assert set(rec["rms_px"]) == {"2", "3", "auto"}
    assert 0 < rec["rms_px"]["auto"] < 0.02, rec
    assert rec["auto_over_best"] < 1.1, rec
    assert abs(rec["edge_blur_sigma_px"] - 0.7) < 0.15 and 0.004 < rec["board_noise_rel"] < 0.02


def test_speed_tiny_and_its_gate(tmp_path):
    # one run: a render camera and a campaign with 2 local workers (forkserver: the workers
    # are grandchildren, seen only through /proc); then camval gate judges the document
    campaign = tmp_path / "tiny.toml"
    campaign.write_text(TINY_CAMPAIGN)
    out = tmp_path / "results"
    run("speed", "--cameras", "17", "--render-repeats", "1", "--campaign", campaign,
        "-j", "2", "--no-first", "--out-dir", out)
    [path] = documents(out)
    doc = check_document(path, "speed")
    render = doc["records"]["raycast_area/memory/17/area"]
    assert render["status"] == "ok", render
    # a 640x480 render holds at least its float32 image; the process at least its imports
    assert render["peak_rss_MB"] > 640 * 480 * 4 / 1e6
    assert 0 < render["seconds"]["render_per_image"] <= render["wall_s"]["values"][-1] * 2
    rec = doc["records"]["campaign/tiny/repeat-1"]
    assert rec["status"] == "ok", rec
    workers = [p for p in rec["processes"] if p["role"] == "worker"]
    # the one job ran in a worker: it rendered 6 images, which takes CPU and memory there
    assert workers and max(p["cpu_s"] for p in workers) > 0.1
    assert max(p["peak_rss_bytes"] for p in workers) > 50 * 2**20
    assert rec["seconds"]["campaign_cpu"] >= max(p["cpu_s"] for p in workers)
    summary = doc["records"]["speed/summary"]
    assert summary["peak_rss_worker_bytes"] == max(p["peak_rss_bytes"] for p in workers)
    assert set(summary["load_average"]) == {"start", "after_render", "after_campaign"}

    # the speed gate reads the document; against itself it passes, against a baseline
    # three times faster it fails (the margins are below 200%)
    gate = [sys.executable, "-m", "camval.cli", "gate", str(path), "--spec",
            str(REPO / "campaigns" / "gate-speed.toml")]
    r = subprocess.run([*gate, "--baseline", str(path)], capture_output=True, text=True,
                       cwd=REPO, env=ENV)
    assert r.returncode == 0, r.stdout + r.stderr
    fast = json.loads(path.read_text())
    for rec in fast["records"].values():
        for k, v in (rec.get("seconds") or {}).items():
            rec["seconds"][k] = v / 3
    base = tmp_path / "fast.json"
    base.write_text(json.dumps(fast))
    r = subprocess.run([*gate, "--baseline", str(base)], capture_output=True, text=True,
                       cwd=REPO, env=ENV)
    assert r.returncode == 1, r.stdout + r.stderr
    for field in ("seconds.render_per_image", "seconds.campaign", "seconds.campaign_cpu"):
        assert re.search(rf"\s{re.escape(field)}\s", r.stdout), r.stdout


@pytest.mark.slow
def test_legacy_signature_tiny(tmp_path):
    run("legacy_signature", "--cameras", "17", "--spp", "1", "-j", "1",
        "--run-dir", tmp_path / "run", "--out-dir", tmp_path / "results")
    [path] = documents(tmp_path / "results")
    doc = check_document(path, "legacy_signature")
    assert "legacy_signature/summary" in doc["records"]
    assert {r["mode"] for n, r in doc["records"].items() if n != "legacy_signature/summary"} \
        == {"legacy", "clean"}


def test_speed_campaign_and_gate_parse():
    from harness.campaign import load_campaign
    from harness.gate import load_gate_spec

    campaign = load_campaign(REPO / "campaigns" / "speed.toml")
    assert [r.name for r in campaign.renderers] == ["raycast"]
    spec = load_gate_spec(REPO / "campaigns" / "gate-speed.toml")
    assert [(g.field, g.relative) for g in spec.regressions] == [
        ("seconds.render_per_image", True), ("seconds.campaign_cpu", True),
        ("seconds.campaign", True)]


def test_every_harness_name_resolves(common):
    # the one place where the benchmarks import the harness's stages from
    for name in common.STAGES:
        assert getattr(common, name) is not None, name


def test_bench_corners_aruco_corners_are_the_boards_points(common):
    # OpenCV's AprilTag detector's 4 corners per marker land on the board's points of that
    # tag (the order mapped, camval's pixel convention): on a pinhole render every tag is
    # found and each corner is within a pixel of its exact projection (its cornerSubPix
    # polish errs ~0.2 px RMS), where a wrong order or a half-pixel shift would not be
    from targets_render import pinhole, render

    from targets.boards import load_target
    from targets.centroids import projected_points
    bench = importlib.import_module("bench_corners")
    t = load_target("apriltag")
    a = np.radians(20.0)
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    Rt = np.vstack((Rx, [-0.5, -0.45, 1.6]))
    model = pinhole(800, 800, 700.0)
    img = render(model, t.pattern(), Rt, K=4)
    det = bench.detect_aruco(img, t)
    truth = projected_points(model, t, Rt)
    assert det.status == "ok" and det.n_found == t.Npoints
    e = np.linalg.norm(det.q - truth, axis=-1)
    assert e.max() < 1.0
    assert np.sqrt(np.mean(e ** 2)) < 0.4
    # the mean error is no half-pixel shift of the convention
    assert np.abs(np.mean(det.q - truth, axis=0)).max() < 0.15


def test_bench_corners_timing_keeps_the_first_detection_apart(common):
    bench = importlib.import_module("bench_corners")
    rows = [{"target": "apriltag", "method": "camval", "shape": [1024, 1024],
             "seconds": [0.2, 0.3], "cpu_seconds": [0.1, 0.12], "first_cpu_seconds": f}
            for f in (0.4, 0.15)]
    (t,) = bench.timing_rows(rows)
    assert t["shape"] == "1024x1024" and t["images"] == 4
    assert t["cpu_seconds_max"] == 0.12 and t["cpu_seconds_median"] == 0.11
    assert t["first_cpu_seconds_max"] == 0.4

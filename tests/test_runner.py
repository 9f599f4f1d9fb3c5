r'''The runner: stages, failures as records, resume, determinism, local and Dask executors

The jobs are real (catalogue camera, pose planner, ray-cast renderer, dot
detector, jpl calibrator, comparison); the campaign is small: the 640x480
Rocky8 hazcam under CAHV at K=4, and the SuperCam extra, which cannot see a
board (its planner failure is a record).
'''

import contextlib
import copy
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from harness.campaign import parse_campaign
from harness.executors import run_jobs
from harness.jobs import Job, RunnerError, expand_jobs
from harness.records import RunStore, job_filename, without_timings
from harness.runner import run_campaign, run_job
from harness.stages import render_summary

ROOT = Path(__file__).resolve().parent.parent
SMALL = {"name": "small", "cameras": [17, "SuperCam"], "models": ["CAHV"], "keep_images": True,
         "renderer": [{"name": "raycast", "spp": 4}], "calibrator": [{"name": "jpl"}]}
OK = "17/CAHV/dots/raycast[spp=4,adaptive,coverage=area]/jpl[CAHV]"
NOT_VISIBLE = "SuperCam/CAHV/dots/raycast[spp=4,adaptive,coverage=area]/jpl[CAHV]"


def _campaign():
    return parse_campaign(SMALL, source="small")


def _comparable(doc):
    return {k: without_timings(r) for k, r in doc["records"].items()}


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("runs") / "a"
    doc = run_campaign(_campaign(), d, workers=1, progress=False)
    return d, doc


def test_records_have_real_numbers(first_run):
    d, doc = first_run
    assert sorted(doc["records"]) == sorted([OK, NOT_VISIBLE])
    r = doc["records"][OK]
    assert r["status"] == "ok" and r["reason"] == "" and r["stage"] == ""
    assert r["camera"] == "17" and r["camera_label"] == "Rocky8 rear hazcam left"
    assert r["image_size"] == [640, 480]
    assert r["detections"]["n_expected"] == 600 and r["detections"]["n_found"] == 600
    assert r["detections"]["failed_poses"] == [] and r["detections"]["failed_reasons"] == {}
    # K=4 exact ray casting: residuals of hundredths of a pixel at most
    assert 1e-4 < r["residuals"]["rms"] < 0.05 and r["residuals"]["n"] == 600
    assert abs(r["params"]["Hc"]) < 0.2 and abs(r["params"]["theta_deg"]) < 0.05
    assert r["params"]["O_deg"] is None           # a CAHV has no O
    assert 0 < r["projection"]["rms"] < 0.05
    assert r["projection"]["rms"] == r["projection"]["rotation"]["rms"]
    assert set(r["projection"]) >= {"rotation", "intrinsics", "world"}
    for k in ("poses", "render", "render_per_image", "render_first_image", "detect",
              "calibrate", "compare"):
        assert r["seconds"][k] > 0
    assert r["seconds"]["render_per_image"] <= r["seconds"]["render"] / 3   # median of 6
    assert r["info"]["render"]["samples"] > 0 and 0 < r["info"]["render"]["adaptive_fraction"] < 1
    assert r["info"]["render"]["images"] == 6
    assert r["versions"]["renderer"].startswith("raycast")
    assert r["artifacts"]["map"].startswith("maps/")
    assert (d / r["artifacts"]["map"]).is_file()
    # keep_images: the six renders (16-bit PNG) and the detections
    from renderers.png import load_png
    assert len(r["artifacts"]["images"]) == 6
    im = load_png(d / r["artifacts"]["images"][0])
    assert im.shape == (480, 640) and 0 <= im.min() < 0.5 < im.max() <= 1
    import numpy as np
    dets = np.load(d / r["artifacts"]["detections"])
    assert dets["q"].shape == (6, 100, 2) and dets["Rt_cam_board"].shape == (6, 4, 3)
    f = doc["records"][NOT_VISIBLE]
    assert f["status"] == "not-applicable" and f["stage"] == "poses"   # off-axis: not a failure
    assert "outside the 2048x2048 image" in f["reason"]
    assert doc["adapters"]["renderers"]["raycast"].startswith("raycast")
    assert doc["adapters"]["libraries"]["numpy"]
    assert doc["execution"]["jobs"] == 2 and doc["execution"]["jobs_run"] == 2
    on_disk = json.loads((d / "run.json").read_text())
    assert on_disk["records"] == doc["records"]
    # the verdict's floor and renderer in the campaign's verdict_modes (rotation by
    # default), which run.json states; the total keeps every mode
    assert on_disk["campaign"]["verdict_modes"] == ["rotation"]
    for part in ("floor", "renderer"):
        assert set(r["verdict"][part]["projection"]) == {"rms", "max", "rotation"}


def test_verdict_modes_add_the_other_projection_modes(first_run):
    r'''verdict_modes = every mode: the floor and renderer get "intrinsics" and (jpl: the
world frame) "world"; every other figure of the record is the same, bit for bit'''
    import dataclasses

    from harness.compare import PROJECTION_MODES
    _, doc = first_run
    job = [j for j in expand_jobs(_campaign()) if j.camera == "17"][0]
    assert job.verdict_modes == ("rotation",)
    (r,) = run_job(dataclasses.replace(job, verdict_modes=PROJECTION_MODES,
                                       keep_images=False, keep_maps=False))["records"]
    base = copy.deepcopy(doc["records"][OK])
    for part in ("floor", "renderer"):
        proj = r["verdict"][part]["projection"]
        assert set(proj) == {"rms", "max", "rotation", "intrinsics", "world"}
        assert proj["intrinsics"]["rms"] is not None and proj["world"]["rms"] is not None
        del proj["intrinsics"], proj["world"]
    for rec in (r, base):
        rec.pop("artifacts")
    assert without_timings(r) == without_timings(base)


def test_resume_redoes_only_missing_jobs(first_run, tmp_path):
    d, doc = first_run
    import shutil
    run = tmp_path / "copy"
    shutil.copytree(d, run)
    (run / "run.json").unlink()
    files = {p.name: p.stat().st_mtime_ns for p in (run / "records").glob("*.json")}
    gone = job_filename("17/CAHV/dots/raycast[spp=4,adaptive,coverage=area]")
    (run / "records" / gone).unlink()
    again = run_campaign(_campaign(), run, workers=1, progress=False, resume=True)
    assert again["execution"]["jobs_run"] == 1
    for name, mtime in files.items():
        if name != gone:
            assert (run / "records" / name).stat().st_mtime_ns == mtime
    assert _comparable(again) == _comparable(doc)
    # nothing left to do
    third = run_campaign(_campaign(), run, workers=1, progress=False, resume=True)
    assert third["execution"]["jobs_run"] == 0
    assert _comparable(third) == _comparable(doc)


def test_adapter_versions_are_kept_per_renderer_label():
    from harness.runner import adapters_from_records
    recs = {"a": {"renderer": "command", "settings": {"label": "pathtracer"},
                  "versions": {"renderer": "pt 2.1"}},
            "b": {"renderer": "command", "settings": {"label": "raster"},
                  "versions": {"renderer": "raster 0.9"}},
            "c": {"renderer": "raycast", "settings": {}, "versions": {"renderer": "raycast x"}}}
    got = adapters_from_records(recs)["renderers"]
    assert got == {"pathtracer": "pt 2.1", "raster": "raster 0.9", "raycast": "raycast x"}


def test_stage_failures_are_records():
    c = parse_campaign({"cameras": [15], "models": ["CAHVORE", "CAHV"],
                        "calibrator": [{"name": "jpl"}, {"name": "mrcal"}]})
    na_job, cahv_job = expand_jobs(c)
    out = run_job(na_job)
    assert [(r["calibrator"], r["status"], r["stage"]) for r in out["records"]] == [
        ("jpl", "not-applicable", "camera"), ("mrcal", "not-applicable", "camera")]
    assert out["records"][0]["reason"] == ("camera 15 is a CAHVOR; a CAHVORE cannot be derived "
                                           "from it")
    # a renderer that is gone by the time the job runs: a failed render, not a crash
    import dataclasses
    gone = dataclasses.replace(cahv_job, renderer="no-such-renderer",
                               key="15/CAHV/dots/no-such-renderer[spp=16,adaptive]")
    out = run_job(gone)
    assert {r["stage"] for r in out["records"]} == {"render"}
    assert "unknown renderer 'no-such-renderer'" in out["records"][0]["reason"]


def test_render_summary_keeps_only_deterministic_metadata():
    m = [{"samples": 10, "adaptive_fraction": 0.5, "ray_cache": "cold", "seconds": 1.0},
         {"samples": 12, "adaptive_fraction": 0.25, "ray_cache": "warm", "seconds": 2.0}]
    assert render_summary(m) == {"images": 2, "samples": 22, "adaptive_fraction": 0.375}


def test_progress_lines_when_not_a_tty(tmp_path, capsys):
    c = parse_campaign(dict(SMALL, cameras=["SuperCam"]))
    store = RunStore.create(tmp_path / "r", c.as_dict())
    assert run_jobs(expand_jobs(c), store, workers=1, progress=True) == 1
    err = capsys.readouterr().err
    assert "[1/1] SuperCam/CAHV/dots/raycast[spp=4,adaptive,coverage=area]: 1 not-applicable" in err
    assert "ETA 0 s" in err


def test_executor_usage_errors(tmp_path):
    store = RunStore.create(tmp_path / "r", {"name": "x"})
    with pytest.raises(RunnerError, match="unknown executor 'slurm'; known: local, dask"):
        run_jobs([], store, executor="slurm")
    with pytest.raises(RunnerError, match="--executor dask needs --scheduler ADDRESS"):
        run_jobs([], store, executor="dask")
    with pytest.raises(RunnerError, match="same job twice: 15/CAHV/dots"):
        expand_jobs(parse_campaign({"cameras": [15, "MER B navcam left"], "models": ["CAHV"]}))
    assert Job(key="k", camera="1", camera_key="1", family="CAHV", target="dots",
               renderer="raycast", settings={"spp": 1, "adaptive": False},
               calibrators=()).fullname("jpl", "CAHV") == \
        "1/CAHV/dots/raycast[spp=1,full,coverage=area]/jpl[CAHV]"


@pytest.mark.parametrize("args, message", [
    (["--resume", "RUN", "campaigns/quick.toml"], "give no CAMPAIGN and no --out"),
    (["--executor", "dask"], "--executor dask needs --scheduler"),
    (["--scheduler", "tcp://x:1"], "--scheduler is for --executor dask"),
    (["-j", "0"], "-j must be >= 1"),
    (["--resume", "/nonexistent/run"], "not a camval run directory"),
])
def test_verify_usage_errors_exit_2(args, message):
    out = subprocess.run([sys.executable, "-m", "camval.cli", "verify", *args],
                         capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 2, out.stderr
    assert message in out.stderr and len(out.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_process_pool_gives_the_same_records(first_run, tmp_path):
    _, doc = first_run
    other = run_campaign(_campaign(), tmp_path / "pool", workers=2, progress=False)
    assert other["execution"]["workers"] == 2
    assert _comparable(other) == _comparable(doc)
    # before the two workers started, the kernels were compiled here, or found cached
    # (first_run rendered in this process, so they are, unless a kernel changed since)
    warm = other["execution"]["warm_up"]
    assert (warm["cached"], warm["renders"]) in ((["raycast", "jpl"], []),
                                                 ([], ["raycast/CAHV", "raycast/dots/largest"]))
    assert doc["execution"]["warm_up"] is None       # one worker: the jobs run here


# A loaded machine (two cores shared by several test runs and compilations) answers
# slowly: distributed's default 30 s connect and comm timeouts and its 5 minute worker
# time-to-live are raised for the clusters of these tests. Nothing is asserted on time.
PATIENT_DASK = {"distributed.comm.timeouts.connect": "600s",
                "distributed.comm.timeouts.tcp": "600s",
                "distributed.scheduler.worker-ttl": None}
PATIENT_DASK_ENV = {"DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "600s",
                    "DASK_DISTRIBUTED__COMM__TIMEOUTS__TCP": "600s"}


@contextlib.contextmanager
def patient_local_cluster(**kw):
    r'''An in-process LocalCluster (one worker, one thread) with patient timeouts'''
    import dask.config
    from dask.distributed import LocalCluster
    with dask.config.set(PATIENT_DASK), warnings.catch_warnings():
        # distributed warns when a loaded machine is slow to make its scratch directory
        warnings.filterwarnings("ignore", message="Creating scratch directories",
                                category=UserWarning)
        with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                          dashboard_address=None, **kw) as cluster:
            yield cluster


@pytest.mark.slow
def test_dask_local_cluster_gives_the_same_records(first_run, tmp_path):
    _, doc = first_run
    with patient_local_cluster() as cluster:
        other = run_campaign(_campaign(), tmp_path / "dask", executor="dask",
                             scheduler=cluster.scheduler_address, progress=False)
    assert other["execution"]["executor"] == "dask"
    assert _comparable(other) == _comparable(doc)
    assert os.listdir(tmp_path / "dask" / "maps")


# --- camera response in campaigns -------------------------------------------------------
NOISY = {"full_well_e": 20000.0, "psf": {"kind": "gaussian", "sigma_px": 0.7},
         "shot_noise": {}, "read_noise": {"sigma_e": 12.0}, "quantise": {"bits": 12}}
RESPONSE = dict(SMALL, cameras=[17], seed=3, keep_images=True,
                renderer=[{"name": "raycast", "spp": 4, "response": ["clean", "noisy"]}],
                response={"clean": {}, "noisy": NOISY})
NOISY_KEY = "17/CAHV/dots/raycast[spp=4,adaptive,coverage=area,response=noisy]"


@pytest.fixture(scope="module")
def response_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("runs") / "response"
    campaign = parse_campaign(RESPONSE, source="response")
    doc = run_campaign(campaign, d, workers=1, progress=False)
    return d, doc, campaign


def test_noisy_records_differ_from_clean_and_list_their_stages(first_run, response_run):
    _, clean_doc = first_run
    d, doc, _ = response_run
    assert sorted(doc["records"]) == sorted([OK, NOISY_KEY + "/jpl[CAHV]"])
    clean, noisy = doc["records"][OK], doc["records"][NOISY_KEY + "/jpl[CAHV]"]
    assert noisy["status"] == "ok" and noisy["settings"]["response"] == "noisy"
    # the clean job is the one of a campaign without profiles, apart from the profile's name
    assert clean["response"]["profile"] == "clean" and clean["response"]["stages"] == []
    before = copy.deepcopy(without_timings(clean_doc["records"][OK]))
    assert before["response"]["profile"] == ""
    before["response"]["profile"] = "clean"
    assert without_timings(clean) == before
    assert "response" not in clean["seconds"]
    # what ran, with which parameters, in which order, and what it cost
    assert noisy["response"]["profile"] == "noisy"
    assert noisy["response"]["full_well_e"] == 20000.0
    assert noisy["response"]["stages"] == [
        {"stage": "psf", "params": {"kind": "gaussian", "sigma_px": 0.7}},
        {"stage": "shot_noise", "params": {}},
        {"stage": "read_noise", "params": {"sigma_e": 12.0}},
        {"stage": "quantise", "params": {"bits": 12}}]
    assert noisy["response"]["seed"]["campaign"] == 3
    secs = noisy["seconds"]["response_stages"]
    assert set(secs) == {"setup", "psf", "shot_noise", "read_noise", "quantise"}
    assert all(v > 0 for v in secs.values())
    assert noisy["seconds"]["response"] == pytest.approx(sum(secs.values()))
    # a board render models no shading, texture or shadows
    for r in (clean, noisy):
        assert r["features"] == {"shading": False, "texture": False, "shadows": False}
    # noise and blur: same detections, a different (and still sub-pixel) fit
    assert noisy["detections"]["n_found"] == 600
    assert noisy["residuals"]["rms"] != clean["residuals"]["rms"]
    assert clean["residuals"]["rms"] < noisy["residuals"]["rms"] < 0.05
    assert noisy["params"]["Hc"] != clean["params"]["Hc"]
    assert noisy["projection"]["rms"] < 0.05
    # the kept images are what the detector saw: 12-bit levels, not the clean render
    from renderers.png import load_png
    im_noisy = load_png(d / noisy["artifacts"]["images"][0]).astype(np.float64)
    im_clean = load_png(d / clean["artifacts"]["images"][0]).astype(np.float64)
    k = im_noisy * 4095
    assert np.max(np.abs(k - np.round(k))) < 0.1
    assert np.max(np.abs(im_noisy - im_clean)) > 0.01


def test_noisy_job_is_reproducible_bit_for_bit(response_run, tmp_path):
    d, doc, campaign = response_run
    (job,) = [j for j in expand_jobs(campaign, run_dir=tmp_path) if j.key == NOISY_KEY]
    (again,) = run_job(job)["records"]
    first = doc["records"][NOISY_KEY + "/jpl[CAHV]"]
    assert without_timings(again) == without_timings(first)
    # the images the detector saw, byte for byte, and the projection-difference map
    assert len(first["artifacts"]["images"]) == 6
    for rel in first["artifacts"]["images"] + [first["artifacts"]["detections"],
                                               first["artifacts"]["map"]]:
        assert (tmp_path / rel).read_bytes() == (d / rel).read_bytes(), rel


def test_response_stage_noise_depends_on_the_job_and_the_seeds(response_run):
    import dataclasses

    from harness.stages import camera_stage, noise_seed, response_stage
    _, _, campaign = response_run
    (job,) = [j for j in expand_jobs(campaign) if j.key == NOISY_KEY]
    _, truth = camera_stage(job)
    flat = [np.full((truth.height, truth.width), 0.5, dtype=np.float32)] * 2
    a, secs = response_stage(job, truth, flat)
    b, _ = response_stage(job, truth, flat)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0], a[1])            # each image its own noise
    other = dataclasses.replace(job, key=job.key + "x")
    c, _ = response_stage(other, truth, flat)
    assert not np.array_equal(a[0], c[0])
    d, _ = response_stage(dataclasses.replace(job, seed=4), truth, flat)
    assert not np.array_equal(a[0], d[0])
    assert noise_seed(job, 1)[:2] == [3, 0] and noise_seed(job, 1)[-1] == 1
    # the centre of a flat image: shot + read noise of a 0.5 well, 12-bit levels
    e = a[0][100:380, 100:540].astype(np.float64) * 20000
    assert abs(e.var() / (10000 + 144 + 4.88 ** 2 / 12) - 1) < 0.03
    # a clean job passes the images through untouched
    clean = dataclasses.replace(job, response={}, response_name="clean")
    out, secs = response_stage(clean, truth, flat)
    assert out is flat and secs == {}


def test_a_bad_response_is_a_failed_record():
    import dataclasses
    (job,) = expand_jobs(parse_campaign(dict(SMALL, cameras=[17])))
    bad = dataclasses.replace(job, response={"shot_noise": {}, "quantise": {"bits": 9}},
                              response_name="bad")
    (rec,) = run_job(bad)["records"]
    assert rec["status"] == "failed" and rec["stage"] == "response"
    assert rec["reason"] == "quantise.bits = 9; known: 8, 10, 12, 14, 16"
    assert rec["response"]["error"] == rec["reason"]
    assert rec["features"] == {"shading": False, "texture": False, "shadows": False}


def test_a_renderer_that_cannot_render_the_camera_is_not_applicable():
    # the legacy renderer's R1 sign defect means nothing for a CAHV camera
    (job,) = expand_jobs(parse_campaign(dict(SMALL, cameras=[17], renderer=[
        {"name": "faulty", "spp": 1, "options": {"fault": "r1_sign"}}])))
    (rec,) = run_job(job)["records"]
    assert (rec["status"], rec["stage"]) == ("not-applicable", "render")
    assert "needs a CAHVOR or CAHVORE" in rec["reason"]
    # a renderer that raises anything else is failed
    (job,) = expand_jobs(parse_campaign(dict(SMALL, cameras=[17], renderer=[
        {"name": "faulty", "spp": 1, "options": {"fault": "no-such-fault"}}])))
    (rec,) = run_job(job)["records"]
    assert (rec["status"], rec["stage"]) == ("failed", "render")


def _die(job):
    os._exit(3)   # a worker killed mid-job (out of memory, SIGKILL)


def test_dead_worker_is_reported_and_retried_on_resume(tmp_path):
    c = parse_campaign(dict(SMALL, cameras=["SuperCam"]))
    jobs = expand_jobs(c)
    store = RunStore.create(tmp_path / "r", c.as_dict())
    assert run_jobs(jobs, store, fn=_die, workers=2, progress=False) == 1
    (rec,) = store.records().values()
    assert rec["status"] == "failed" and rec["stage"] == "worker"
    assert "BrokenProcessPool" in rec["reason"]
    assert store.done_jobs() == set()
    assert run_jobs(jobs, store, workers=1, progress=False) == 1
    (rec,) = store.records().values()
    assert rec["stage"] == "poses"
    assert store.done_jobs() == {jobs[0].key}


def test_rich_progress_bar_on_a_terminal():
    import io

    from harness.progress import Progress

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    term = Terminal()
    bar = Progress(stream=term)
    assert bar.bar is not None
    bar.stage("jobs", total=2)
    bar.advance("15/CAHV/dots/raycast[spp=16,adaptive,coverage=area]: 3 ok",
                short="15/CAHV: 3 ok")
    bar.advance("17/CAHV/dots/raycast[spp=16,adaptive,coverage=area]: 1 failed",
                short="17/CAHV: 1 failed")
    bar.close()
    out = term.getvalue()
    assert "2/2" in out and "ETA" in out and "1 failed" in out


@pytest.mark.slow
def test_cli_dask_executor_with_a_scheduler_address(first_run, tmp_path):
    _, doc = first_run
    camp = tmp_path / "small.toml"
    camp.write_text('name = "small"\ncameras = [17, "SuperCam"]\nmodels = ["CAHV"]\n'
                    'keep_images = true\n[[renderer]]\nname = "raycast"\nspp = 4\n'
                    '[[calibrator]]\nname = "jpl"\n')
    with patient_local_cluster(protocol="tcp") as cluster:
        assert cluster.scheduler_address.startswith("tcp://")
        out = subprocess.run([sys.executable, "-m", "camval.cli", "verify", str(camp),
                              "--executor", "dask", "--scheduler", cluster.scheduler_address,
                              "--out", str(tmp_path / "run"), "--no-report", "--quiet"],
                             capture_output=True, text=True, cwd=ROOT, timeout=1800,
                             env=dict(os.environ, **PATIENT_DASK_ENV))
    assert out.returncode == 0, out.stderr[-3000:]
    other = json.loads((tmp_path / "run" / "run.json").read_text())
    assert other["execution"]["executor"] == "dask"
    assert other["execution"]["scheduler"] == cluster.scheduler_address
    assert _comparable(other) == _comparable(doc)

r'''The runner: stages, failures as records, resume, determinism, local and Dask executors

The jobs are real (catalogue camera, pose planner, ray-cast renderer, dot
detector, jpl calibrator, comparison); the campaign is small: the 640x480
Rocky8 hazcam under CAHV at K=4, and the SuperCam extra, which cannot see a
board (its planner failure is a record).
'''

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from harness.campaign import parse_campaign
from harness.records import RunStore, job_filename, without_timings
from harness.runner import (
    Job,
    RunnerError,
    expand_jobs,
    render_summary,
    run_campaign,
    run_job,
    run_jobs,
)

ROOT = Path(__file__).resolve().parent.parent
SMALL = {"name": "small", "cameras": [17, "SuperCam"], "models": ["CAHV"], "keep_images": True,
         "renderer": [{"name": "raycast", "spp": 4}], "calibrator": [{"name": "jpl"}]}
OK = "17/CAHV/dots/raycast[spp=4,adaptive]/jpl[CAHV]"
NOT_VISIBLE = "SuperCam/CAHV/dots/raycast[spp=4,adaptive]/jpl[CAHV]"


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
    # K=4 exact ray casting: residuals of hundredths of a pixel at most
    assert 1e-4 < r["residuals"]["rms"] < 0.05 and r["residuals"]["n"] == 600
    assert abs(r["params"]["Hc"]) < 0.2 and abs(r["params"]["theta_deg"]) < 0.05
    assert r["params"]["O_deg"] is None           # a CAHV has no O
    assert 0 < r["projection"]["rms"] < 0.05
    assert r["projection"]["rms"] == r["projection"]["rotation"]["rms"]
    assert set(r["projection"]) >= {"rotation", "intrinsics", "world"}
    for k in ("poses", "render", "render_per_image", "detect", "calibrate", "compare"):
        assert r["seconds"][k] > 0
    assert r["info"]["render"]["samples"] > 0 and 0 < r["info"]["render"]["adaptive_fraction"] < 1
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
    assert f["status"] == "failed" and f["stage"] == "poses"
    assert "outside the 2048x2048 image" in f["reason"]
    assert doc["adapters"]["renderers"]["raycast"].startswith("raycast")
    assert doc["adapters"]["libraries"]["numpy"]
    assert doc["execution"]["jobs"] == 2 and doc["execution"]["jobs_run"] == 2
    on_disk = json.loads((d / "run.json").read_text())
    assert on_disk["records"] == doc["records"]


def test_resume_redoes_only_missing_jobs(first_run, tmp_path):
    d, doc = first_run
    import shutil
    run = tmp_path / "copy"
    shutil.copytree(d, run)
    (run / "run.json").unlink()
    files = {p.name: p.stat().st_mtime_ns for p in (run / "records").glob("*.json")}
    gone = job_filename("17/CAHV/dots/raycast[spp=4,adaptive]")
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
    assert render_summary(m) == {"samples": 22, "adaptive_fraction": 0.375}


def test_progress_lines_when_not_a_tty(tmp_path, capsys):
    c = parse_campaign(dict(SMALL, cameras=["SuperCam"]))
    store = RunStore.create(tmp_path / "r", c.as_dict())
    assert run_jobs(expand_jobs(c), store, workers=1, progress=True) == 1
    err = capsys.readouterr().err
    assert "[1/1] SuperCam/CAHV/dots/raycast[spp=4,adaptive]: 1 failed" in err
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
        "1/CAHV/dots/raycast[spp=1,full]/jpl[CAHV]"


@pytest.mark.parametrize("args, message", [
    (["--resume", "RUN", "campaigns/quick.toml"], "give no CAMPAIGN and no --out"),
    (["--executor", "dask"], "--executor dask needs --scheduler"),
    (["--scheduler", "tcp://x:1"], "--scheduler is for --executor dask"),
    (["-j", "0"], "-j must be >= 1"),
    (["--resume", "/nonexistent/run"], "not a camval run directory"),
])
def test_verify_usage_errors_exit_2(args, message):
    out = subprocess.run([sys.executable, "-m", "harness.cli", "verify", *args],
                         capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 2, out.stderr
    assert message in out.stderr and len(out.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_process_pool_gives_the_same_records(first_run, tmp_path):
    _, doc = first_run
    other = run_campaign(_campaign(), tmp_path / "pool", workers=2, progress=False)
    assert other["execution"]["workers"] == 2
    assert _comparable(other) == _comparable(doc)


@pytest.mark.slow
def test_dask_local_cluster_gives_the_same_records(first_run, tmp_path):
    from dask.distributed import LocalCluster
    _, doc = first_run
    with warnings.catch_warnings():
        # distributed warns when a loaded machine is slow to make its scratch directory
        warnings.filterwarnings("ignore", message="Creating scratch directories",
                                category=UserWarning)
        cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                               dashboard_address=None)
    with cluster:
        other = run_campaign(_campaign(), tmp_path / "dask", executor="dask",
                             scheduler=cluster.scheduler_address, progress=False)
    assert other["execution"]["executor"] == "dask"
    assert _comparable(other) == _comparable(doc)
    assert os.listdir(tmp_path / "dask" / "maps")


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

    from harness.runner import _Progress

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    term = Terminal()
    bar = _Progress(2, stream=term)
    assert bar.bar is not None
    bar.advance("15/CAHV/dots/raycast[spp=16,adaptive]", {"ok": 3})
    bar.advance("17/CAHV/dots/raycast[spp=16,adaptive]", {"failed": 1})
    bar.close()
    out = term.getvalue()
    assert "2/2" in out and "ETA" in out and "1 failed" in out


@pytest.mark.slow
def test_cli_dask_executor_with_a_scheduler_address(first_run, tmp_path):
    from dask.distributed import LocalCluster
    _, doc = first_run
    camp = tmp_path / "small.toml"
    camp.write_text('name = "small"\ncameras = [17, "SuperCam"]\nmodels = ["CAHV"]\n'
                    'keep_images = true\n[[renderer]]\nname = "raycast"\nspp = 4\n'
                    '[[calibrator]]\nname = "jpl"\n')
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Creating scratch directories",
                                category=UserWarning)
        cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                               protocol="tcp", dashboard_address=None)
    with cluster:
        assert cluster.scheduler_address.startswith("tcp://")
        out = subprocess.run([sys.executable, "-m", "harness.cli", "verify", str(camp),
                              "--executor", "dask", "--scheduler", cluster.scheduler_address,
                              "--out", str(tmp_path / "run"), "--no-report", "--quiet"],
                             capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    other = json.loads((tmp_path / "run" / "run.json").read_text())
    assert other["execution"]["executor"] == "dask"
    assert other["execution"]["scheduler"] == cluster.scheduler_address
    assert _comparable(other) == _comparable(doc)

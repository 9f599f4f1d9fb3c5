'''harness.progress: a bar with ETA and stage on a terminal, plain lines elsewhere'''

import io
import time
from types import SimpleNamespace

from harness.progress import PROGRESS_DIR, Progress, job_stage, watch_dir


def test_plain_lines_off_a_terminal_with_stage_count_and_eta():
    out = io.StringIO()          # not a terminal: what a CI log gets
    p = Progress(stream=out)
    assert not p.rich
    p.stage("choosing the best models", total=2)
    p.note("camera 15 CAHV mrcal: model benchmark")
    p.advance("camera 15 CAHV mrcal: CAHVOR (1.0 s)")
    p.stage("jobs", total=4)
    p.advance("15/CAHV/dots/raycast: 3 ok")
    p.close()
    lines = out.getvalue().splitlines()
    assert lines[0] == "choosing the best models (2) ..."
    assert lines[1] == "  camera 15 CAHV mrcal: model benchmark"
    assert lines[2].startswith("[1/2] camera 15 CAHV mrcal: CAHVOR (1.0 s)  (elapsed ")
    assert "ETA" in lines[2]
    assert lines[3] == "jobs (4) ..."
    assert lines[4].startswith("[1/4] 15/CAHV/dots/raycast: 3 ok")
    # nothing that redraws a line: no carriage returns, no escape sequences
    assert "\r" not in out.getvalue() and "\x1b" not in out.getvalue()


def test_disabled_prints_nothing():
    out = io.StringIO()
    p = Progress(enabled=False, stream=out)
    p.stage("jobs", total=1)
    p.note("x")
    p.advance("y")
    p.close()
    assert out.getvalue() == ""


def test_a_terminal_gets_a_bar_with_eta_and_the_running_jobs_stages(tmp_path):
    out = io.StringIO()
    p = Progress(stream=out, force_terminal=True)
    assert p.rich
    watch_dir(tmp_path)
    job = SimpleNamespace(key="15/CAHV/dots/raycast", run_dir=str(tmp_path))
    job_stage(job, "render + detect (30 images)")
    p.stage("jobs", total=3, watch=tmp_path)
    assert p._describe() == "15/CAHV: render + detect (30 images)"
    time.sleep(0.7)              # one poll of the workers' stages
    p.advance("17/CAHV/dots/raycast: 3 ok")
    p.close()
    text = out.getvalue()
    assert "jobs" in text and "1/3" in text and "ETA" in text
    assert "15/CAHV: render" in text      # cut to the width of an 80-column terminal
    # a finished job removes its line
    job_stage(job, None)
    assert list((tmp_path / PROGRESS_DIR).iterdir()) == []


def test_job_stage_writes_nothing_without_a_watched_run_dir(tmp_path):
    job_stage(SimpleNamespace(key="k", run_dir=str(tmp_path)), "render")
    assert not (tmp_path / PROGRESS_DIR).exists()
    job_stage(SimpleNamespace(key="k", run_dir=None), "render")     # no run dir: no-op

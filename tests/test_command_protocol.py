r'''The external renderer protocol end to end: stderr in records, not-applicable, labels and
setup that never name records, versions, the installed reader, the persistent mode'''

import json
import os
import shutil
import sys

import numpy as np
import pytest
from render_checks import board_pose, grid_board, small_model

from harness.campaign import CampaignError, parse_campaign
from harness.records import make_fullname
from harness.stages import REASON_MAX_BYTES, REASON_MAX_LINES, failure_reason
from renderers.base import RendererError, RendererNotApplicable, RenderSettings, get_renderer
from renderers.protocol import (
    EXIT_NOT_APPLICABLE,
    STDERR_TAIL_BYTES,
    STDERR_TAIL_LINES,
    read_request,
    tail,
    write_request,
)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLE = os.path.join(ROOT, "examples", "external_renderer.py")


def _script(tmp_path, body, name="renderer.py"):
    path = tmp_path / name
    path.write_text("import sys, json, os\nimport numpy as np\n"
                    "req = json.load(open(sys.argv[1]))\n"
                    "out = os.path.join(os.path.dirname(sys.argv[1]), req['output'])\n" + body)
    return [sys.executable, str(path)]


def test_tail_is_bounded_in_lines_and_bytes():
    text = "\n".join(f"line {i}" for i in range(100))
    t = tail(text)
    assert t.splitlines()[0] == f"[{100 - STDERR_TAIL_LINES} earlier lines cut]"
    assert t.splitlines()[-1] == "line 99" and len(t.splitlines()) == STDERR_TAIL_LINES + 1
    t = tail("\n".join("x" * 1000 + str(i) for i in range(10)))
    assert len(t.encode()) <= STDERR_TAIL_BYTES + 40 and t.endswith("x9")
    assert tail("") == "(no output)"


def test_failure_reason_keeps_the_first_and_the_last_lines():
    short = RendererError("renderer failed (exit 1); stderr:\nTraceback\n  File x\nValueError: bad")
    assert failure_reason(short) == str(short)
    long = RendererError("renderer failed (exit 1); stderr:\n" +
                         "\n".join(f"log {i}" for i in range(500)) + "\nValueError: the end")
    r = failure_reason(long)
    lines = r.splitlines()
    assert lines[0] == "renderer failed (exit 1); stderr:" and lines[-1] == "ValueError: the end"
    assert "lines cut" in lines[1]
    assert len(lines) <= REASON_MAX_LINES and len(r.encode()) <= REASON_MAX_BYTES
    assert failure_reason(ValueError("a\nb")) == "ValueError: a\nb"


def test_a_documented_exit_status_means_not_applicable(tmp_path):
    m = small_model("CAHV", W=32, H=24, f=30.0)
    cmd = _script(tmp_path, "print('log line', file=sys.stderr)\n"
                            "print('sees 100 deg off axis; a pinhole cannot', file=sys.stderr)\n"
                            f"sys.exit({EXIT_NOT_APPLICABLE})\n")
    with pytest.raises(RendererNotApplicable, match="sees 100 deg off axis; a pinhole cannot"):
        get_renderer("command", command=cmd).render(m, grid_board()[0], board_pose(),
                                                     RenderSettings(spp=1))


def test_a_request_says_which_camval_wrote_it(tmp_path):
    from importlib.metadata import version
    m = small_model("CAHVOR", W=32, H=24, f=30.0)
    path = write_request(tmp_path, m, grid_board()[0], board_pose(), RenderSettings(spp=2))
    with open(path) as f:
        raw = json.load(f)
    assert raw["camval"]["version"] == version("camval")
    assert raw["version"] == 2 and raw["mode"] == "image"
    assert read_request(path).mode == "image"


def test_the_reader_is_importable_outside_the_repository(tmp_path):
    # the program runs from elsewhere and finds camval's reader in the installed package
    import subprocess
    out = subprocess.run([sys.executable, "-c", "from renderers.protocol import read_request, "
                          "serve; from renderers.command import read_request as r2; "
                          "print(read_request is r2)"], cwd=tmp_path, capture_output=True,
                         text=True, env={k: v for k, v in os.environ.items()
                                         if k != "PYTHONPATH"})
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "True"


def _campaign(setup, label=None, options=None):
    r = {"name": "command", "spp": 4, "setup": setup}
    if label:
        r["label"] = label
    if options:
        r["options"] = options
    return parse_campaign({"name": "t", "cameras": [17], "models": ["CAHV"],
                           "targets": ["dots"], "poses": {"n": 3, "seed": 0},
                           "renderer": [r], "calibrator": [{"name": "jpl"}]})


def test_setup_never_names_records_and_label_does():
    from harness.jobs import expand_jobs
    a = expand_jobs(_campaign({"command": [sys.executable, "/a/r.py"], "timeout": 600}))
    b = expand_jobs(_campaign({"command": [sys.executable, "/moved/r.py"], "timeout": 900,
                               "env": {"X": "1"}, "version_command": ["r", "--version"]}))
    assert [j.key for j in a] == [j.key for j in b] == ["17/CAHV/dots/command[spp=4,adaptive]"]
    assert a[0].fullname("jpl", "CAHV") == "17/CAHV/dots/command[spp=4,adaptive]/jpl[CAHV]"
    assert b[0].settings["setup"]["timeout"] == 900
    c = expand_jobs(_campaign({"command": ["x"]}, label="mysim", options={"quality": "high"}))
    assert c[0].key == "17/CAHV/dots/mysim[spp=4,adaptive,quality=high]"
    # names without a label are what they always were
    assert make_fullname("15", "CAHVOR", "dots", "raycast", {"spp": 16, "adaptive": True},
                         "jpl", "CAHVOR") == \
        "15/CAHVOR/dots/raycast[spp=16,adaptive,coverage=area]/jpl[CAHVOR]"


def test_campaign_mistakes_about_setup_and_labels():
    with pytest.raises(CampaignError, match=r"command, timeout say how to run 'command'.*setup"):
        _campaign({}, options={"command": ["x"], "timeout": 3}).validate()
    with pytest.raises(CampaignError, match=r"setup: timout unknown to 'command'; its setup: "
                                            r"command, timeout"):
        _campaign({"command": ["x"], "timout": 3}).validate()
    with pytest.raises(CampaignError, match=r"setup: command unknown to 'raycast'"):
        parse_campaign({"cameras": [17], "renderer": [
            {"name": "raycast", "setup": {"command": ["a"]}}]}).validate()
    with pytest.raises(CampaignError, match="label: expected a name"):
        _campaign({}, label="a/b")
    with pytest.raises(CampaignError, match="distinct labels"):
        parse_campaign({"cameras": [17], "renderer": [
            {"name": "command", "setup": {"command": ["a"]}},
            {"name": "command", "setup": {"command": ["b"]}}]})


def test_persistent_mode_answers_and_survives_failures(tmp_path):
    m = small_model("CAHVORE", W=48, H=32, f=40.0)
    pat, _ = grid_board()
    r = get_renderer("command", command=[sys.executable, EXAMPLE], persistent=True,
                     output_format="npy")
    try:
        a = r.render(m, pat, board_pose(20, 1.0), RenderSettings(spp=2))
        ref = get_renderer("raycast").render(m, pat, board_pose(20, 1.0), RenderSettings(spp=2))
        np.testing.assert_array_equal(a.image, ref.image)
        pid = next(iter(r._procs.values())).proc.pid
        with pytest.raises(RendererNotApplicable, match="too wide for me"):
            r.render(m, pat, board_pose(), RenderSettings(spp=1, options={
                "not_applicable": "too wide for me"}))
        with pytest.raises(RendererError, match=r"asked to fail \(yes\)[\s\S]*a log line"):
            r.render(m, pat, board_pose(), RenderSettings(spp=1, options={"fail": "yes"}))
        r.render(m, pat, board_pose(), RenderSettings(spp=1))
        # one process served every request
        assert next(iter(r._procs.values())).proc.pid == pid
        with pytest.raises(RendererError, match="no answer within 1 s"):
            r.render(m, pat, board_pose(), RenderSettings(spp=1, options={
                "sleep": 30, "timeout": 1}))
        # a stopped program is started again for the next request
        r.render(m, pat, board_pose(), RenderSettings(spp=1))
        assert next(iter(r._procs.values())).proc.pid != pid
    finally:
        r.close()


def test_a_persistent_program_that_dies_is_a_failure_with_its_stderr(tmp_path):
    prog = tmp_path / "dies.py"
    prog.write_text("import sys\nsys.stdin.readline()\n"
                    "print('out of licences', file=sys.stderr)\nsys.exit(4)\n")
    r = get_renderer("command", command=[sys.executable, str(prog)], persistent=True)
    with pytest.raises(RendererError, match=r"exited \(exit 4\)[\s\S]*out of licences"):
        r.render(small_model("CAHV", W=32, H=24, f=30.0), grid_board()[0], board_pose(),
                 RenderSettings(spp=1))
    r.close()


@pytest.mark.slow
def test_records_keep_stderr_and_a_baseline_joins_after_the_program_moves(tmp_path):
    from harness.gate import check, load_gate_spec, make_baseline
    from harness.runner import run_campaign

    def run(where, setup, options=None):
        c = _campaign(setup, label="example", options=options)
        return run_campaign(c, tmp_path / where, progress=False, workers=1)

    version = [sys.executable, "-c", "print('example renderer 1.2.3')"]
    first = run("first", {"command": [sys.executable, EXAMPLE], "timeout": 600,
                          "output_format": "npy", "version_command": version,
                          "persistent": True})
    (rec,) = first["records"].values()
    assert rec["status"] == "ok", rec["reason"]
    assert rec["fullname"] == "17/CAHV/dots/example[spp=4,adaptive]/jpl[CAHV]"
    assert rec["versions"]["renderer"].endswith("external_renderer.py: example renderer 1.2.3")
    assert rec["settings"]["setup"]["timeout"] == 600

    moved = tmp_path / "elsewhere" / "my_renderer.py"
    moved.parent.mkdir()
    shutil.copy(EXAMPLE, moved)
    second = run("second", {"command": [sys.executable, str(moved)], "timeout": 900,
                            "output_format": "png16"})
    spec = load_gate_spec(os.path.join(ROOT, "campaigns", "gate-regression.toml"))
    assert check(second, spec, make_baseline(first)) == []

    failed = run("failed", {"command": [sys.executable, EXAMPLE]}, options={"fail": "on purpose"})
    (rec,) = failed["records"].values()
    assert rec["status"] == "failed" and rec["stage"] == "render"
    # the whole stderr tail: the log line, the traceback and the exception
    assert "a log line before the failure" in rec["reason"]
    assert "RuntimeError: asked to fail (on purpose)" in rec["reason"]
    assert "Traceback" in rec["reason"]


def test_setup_from_the_command_line():
    from renderers.command import setup_from_cli
    assert setup_from_cli("my-renderer --fast 'a b'", ["timeout=60", 'env={"GPU": "0"}',
                                                        "output_format=npy"]) == {
        "command": ["my-renderer", "--fast", "a b"], "timeout": 60, "env": {"GPU": "0"},
        "output_format": "npy"}
    with pytest.raises(RendererError, match="renderer setup 'speed' is unknown"):
        setup_from_cli(None, ["speed=1"])
    with pytest.raises(RendererError, match="expected KEY=VALUE"):
        setup_from_cli(None, ["timeout"])


def test_env_and_kept_requests(tmp_path):
    cmd = _script(tmp_path, "assert os.environ['MYSIM_QUALITY'] == 'draft'\n"
                            "np.save(out, np.full((req['height'], req['width']), 0.75, "
                            "np.float32))\n")
    keep = tmp_path / "kept"
    r = get_renderer("command", command=cmd, output_format="npy",
                     env={"MYSIM_QUALITY": "draft"}, keep_requests=str(keep))
    res = r.render(small_model("CAHV", W=32, H=24, f=30.0), grid_board()[0], board_pose(),
                   RenderSettings(spp=1))
    assert np.all(res.image == 0.75)
    kept = res.metadata["request_dir"]
    assert os.path.dirname(kept) == str(keep)
    assert sorted(os.listdir(kept)) == ["camera.cahv", "image.npy", "request.json", "scene.json"]

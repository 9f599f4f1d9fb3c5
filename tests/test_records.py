import json
import math
import os

import numpy as np
import pytest

from harness.records import (
    Record,
    RunError,
    RunStore,
    job_filename,
    jsonable,
    load_run,
    make_fullname,
    settings_label,
    without_timings,
    write_json_atomic,
)


def _record(fullname="15/CAHVOR/dots/raycast[spp=16,adaptive]/jpl[CAHVOR]", **kw):
    base = dict(fullname=fullname, camera="15", camera_label="MER B navcam left",
                model="CAHVOR", target="dots", renderer="raycast",
                settings={"spp": 16, "adaptive": True, "options": {}}, calibrator="jpl",
                calibrator_model="CAHVOR", status="ok",
                residuals={"n": 600, "min": 1e-5, "max": 0.004, "rms": 0.001, "mean": 8e-4},
                params={"Hc": 0.003, "theta_deg": None},
                projection={"rms": 0.0007, "max": 0.002}, seconds={"render": 0.3})
    base.update(kw)
    return Record(**base)


def test_fullname_and_settings_label():
    s = {"spp": 4, "adaptive": False, "options": {"noise": 2.0, "legacy": True}}
    assert settings_label(s) == "spp=4,full,legacy=true,noise=2.0"
    assert make_fullname("15", "CAHVOR", "dots", "raycast", s, "mrcal", "CAHVOR") == \
        "15/CAHVOR/dots/raycast[spp=4,full,coverage=area,legacy=true,noise=2.0]/mrcal[CAHVOR]"


def test_response_profile_in_the_fullname():
    s = {"spp": 16, "adaptive": True, "options": {"legacy": True}, "response": "realistic"}
    assert settings_label(s) == "spp=16,adaptive,legacy=true,response=realistic"
    assert make_fullname("15", "CAHVOR", "dots", "raycast", s, "jpl", "CAHVOR") == \
        "15/CAHVOR/dots/raycast[spp=16,adaptive,coverage=area,legacy=true,response=realistic]/jpl[CAHVOR]"
    # no profile, or an empty one: the label a clean record always had
    assert settings_label(dict(s, response="")) == settings_label(
        {"spp": 16, "adaptive": True, "options": {"legacy": True}}) == "spp=16,adaptive,legacy=true"


def test_a_record_from_before_camera_response_loads():
    d = _record().as_dict()
    old = {k: v for k, v in d.items() if k not in ("response", "features")}
    r = Record.from_dict(old)
    assert r.response is None and r.features is None and r == _record()
    noisy = _record(response={"profile": "noisy", "stages": [{"stage": "shot_noise",
                                                             "params": {}}]},
                    features={"shading": False, "texture": False, "shadows": False})
    assert Record.from_dict(json.loads(json.dumps(noisy.as_dict()))) == noisy


def test_jsonable_maps_nan_and_numpy():
    d = jsonable({"a": np.float32(1.5), "b": np.nan, "c": np.arange(3), "d": np.bool_(True),
                  "e": (np.int64(2), math.inf)})
    assert d == {"a": 1.5, "b": None, "c": [0, 1, 2], "d": True, "e": [2, None]}
    json.dumps(d, allow_nan=False)


def test_record_round_trip_and_status_check():
    r = _record()
    d = r.as_dict()
    assert Record.from_dict(json.loads(json.dumps(d))) == r
    assert "seconds" not in without_timings(d) and without_timings(d)["params"]["Hc"] == 0.003
    with pytest.raises(RunError, match="status 'great' is not one of ok, failed"):
        _record(status="great")
    with pytest.raises(RunError, match=r"unknown fields \['bogus'\]"):
        Record.from_dict(dict(d, bogus=1))


def test_write_atomic_leaves_no_temp_and_replaces(tmp_path):
    p = tmp_path / "a" / "doc.json"
    write_json_atomic(p, {"x": 1})
    write_json_atomic(p, {"x": 2})
    assert json.loads(p.read_text()) == {"x": 2}
    assert sorted(os.listdir(p.parent)) == ["doc.json"]
    with pytest.raises(RunError, match="cannot serialise"):
        write_json_atomic(p, {"x": object()})
    assert json.loads(p.read_text()) == {"x": 2}
    assert sorted(os.listdir(p.parent)) == ["doc.json"]


def test_store_save_resume_assemble(tmp_path):
    run = tmp_path / "run"
    store = RunStore.create(run, {"name": "t"})
    with pytest.raises(RunError, match="already holds a run"):
        RunStore.create(run, {"name": "t"})
    a = _record()
    b = _record("15/CAHV/dots/raycast[spp=16,adaptive]/jpl[CAHV]", model="CAHV",
                calibrator_model="CAHV", status="failed", stage="detect",
                reason="the target was found in none of the 6 images")
    store.save_job("15/CAHVOR/dots/raycast[spp=16,adaptive]", [a])
    store.save_job("15/CAHV/dots/raycast[spp=16,adaptive]", [b])
    # a job file cut short (a kill during a non-atomic write) is not "done"
    (store.records_dir / "partial.json").write_text('{"job": "x", "rec')
    again = RunStore.open(run)
    assert again.done_jobs() == {"15/CAHVOR/dots/raycast[spp=16,adaptive]",
                                 "15/CAHV/dots/raycast[spp=16,adaptive]"}
    doc = again.assemble(adapters={"renderers": {"raycast": "raycast 1"}})
    assert list(doc["records"]) == sorted([a.fullname, b.fullname])
    assert doc["schema_version"] == 1 and doc["kind"] == "camval-run"
    assert doc["created"].endswith("Z") and doc["machine"]["cpus"] >= 1
    assert len(doc["source"]["commit"]) == 40
    loaded = load_run(run)
    assert loaded["records"][b.fullname]["reason"].startswith("the target was found")
    assert loaded["records"][a.fullname]["params"]["theta_deg"] is None
    assert load_run(run / "run.json")["records"] == loaded["records"]


def test_load_run_errors(tmp_path):
    with pytest.raises(RunError, match="not a camval run directory"):
        load_run(tmp_path)
    p = tmp_path / "x.json"
    p.write_text('{"kind": "something"}')
    with pytest.raises(RunError, match="kind 'something'; expected one of camval-run"):
        load_run(p)
    p.write_text('{"kind": "camval-run", "schema_version": 99, "records": {}}')
    with pytest.raises(RunError, match="schema version 99"):
        load_run(p)
    p.write_text("{nope")
    with pytest.raises(RunError, match="not a readable JSON document"):
        load_run(p)


def test_job_filename_is_safe_and_unique():
    a = job_filename("file-x.cahvor/CAHV/dots/raycast[spp=16,adaptive]")
    b = job_filename("file-x.cahvor/CAHV/dots/raycast[spp=16,full]")
    assert a != b and "/" not in a and a.endswith(".json")
    assert len(job_filename("x" * 500)) < 100


def test_a_target_found_nowhere_says_its_most_common_reason():
    r'''The detect stage's failure names the reason most images gave, not the alphabetically
first (h-cornertrust: one view's "OpenCV found no 10x10 chessboard" hid five views'
"the board was found, but its corners were dropped")'''
    from types import SimpleNamespace

    from harness.stages import _none_found
    d = [SimpleNamespace(n_found=0, reason=r) for r in
         ["b: corners dropped"] * 5 + ["a: no board"]]
    e = _none_found(d)
    assert e is not None
    assert str(e).endswith("found in none of the 6 images: b: corners dropped (in 5 of them; "
                           "1 other reason)")
    e = _none_found([SimpleNamespace(n_found=0, reason="x")] * 3)
    assert str(e).endswith("found in none of the 3 images: x")
    assert _none_found(d + [SimpleNamespace(n_found=4, reason="")]) is None

import json
import subprocess
import sys
from pathlib import Path

import pytest

from harness.gate import (
    GateUsageError,
    check,
    format_failures,
    load_gate_spec,
    parse_check,
    parse_gate_spec,
)
from harness.records import Record, RunStore

ROOT = Path(__file__).resolve().parent.parent
JPL = "15/CAHVOR/dots/raycast[spp=16,adaptive]/jpl[CAHVOR]"
MRCAL = "15/CAHVOR/dots/raycast[spp=16,adaptive]/mrcal[CAHVOR]"
OPENCV = "17/CAHVORE/dots/raycast[spp=16,adaptive]/opencv[CAHVORE]"


def _rec(fullname, status="ok", rms=0.001, proj=0.0008, theta=0.0002, reason=""):
    cam, fam, tgt, rend, cal = fullname.split("/")
    return Record(
        fullname=fullname, camera=cam, camera_label="", model=fam, target=tgt,
        renderer="raycast", settings={"spp": 16, "adaptive": True, "options": {}},
        calibrator=cal.split("[")[0], calibrator_model=fam, status=status, reason=reason,
        residuals={"n": 600, "min": 0.0, "max": 3 * rms, "rms": rms, "mean": rms},
        params={"Hc": -0.004, "theta_deg": theta} if status == "ok" else None,
        projection={"rms": proj, "max": 3 * proj} if status == "ok" else None).as_dict()


def _doc(*records):
    return {"kind": "camval-run", "schema_version": 1,
            "records": {r["fullname"]: r for r in records}}


SPEC = parse_gate_spec({
    "limits": ["projection.rms:0.002", "residuals.max:0.01"],
    "limit": [{"field": "params.theta_deg", "max": 0.001, "match": "*/jpl[*"}],
    "regressions": ["projection.rms:25%", "residuals.rms:0.0005"],
}, source="spec")


def test_parse_check():
    assert parse_check("projection.rms:10%") == ("projection.rms", 10.0, True)
    assert parse_check("params.Hs*(1+R0):0.001") == ("params.Hs*(1+R0)", 0.001, False)
    for bad, msg in (("projection.rms", "is not 'field:abs' or 'field:N%'"),
                     ("projection.rms:ten%", "tolerance 'ten%'"),
                     (":0.1", "needs a field name"), ("x:-1", "non-negative tolerance")):
        with pytest.raises(GateUsageError, match=msg):
            parse_check(bad)


def test_all_hold():
    run = _doc(_rec(JPL), _rec(MRCAL, theta=None))
    assert check(run, SPEC, run) == []


def test_every_failure_is_collected():
    base = _doc(_rec(JPL), _rec(MRCAL, theta=None), _rec(OPENCV))
    run = _doc(_rec(JPL, proj=0.003, theta=-0.002),          # limit, limit, regression
               _rec(MRCAL, rms=0.0016, theta=None),          # regression (abs), not theta
               )                                             # OPENCV missing
    f = check(run, SPEC, base)
    got = sorted((x.fullname, x.field, x.kind) for x in f)
    assert got == sorted([
        (JPL, "projection.rms", "limit"),
        (JPL, "params.theta_deg", "limit"),
        (JPL, "projection.rms", "regression"),
        (MRCAL, "residuals.rms", "regression"),
        (OPENCV, "record", "missing"),
    ])
    table = format_failures(f)
    lines = table.splitlines()
    assert lines[0].split() == ["fullname", "field", "value", "limit"]
    assert len(lines) == 2 + len(f)
    assert any("0.003" in ln and "<= 0.002" in ln for ln in lines)
    assert any("<= 0.001 (baseline 0.0008 + 25%)" in ln for ln in lines)


def test_status_failures_and_missing_fields():
    failed = _rec(OPENCV, status="failed", reason="calibrator diverged")
    run = _doc(_rec(JPL), failed)
    f = check(run, parse_gate_spec({"limits": ["projection.rms:1"]}))
    assert [(x.fullname, x.kind, x.value) for x in f] == [
        (OPENCV, "status", "failed: calibrator diverged")]
    # a field absent from an ok record fails; null (not estimated) is skipped
    f = check(_doc(_rec(JPL)), parse_gate_spec({"limits": ["params.O_deg:0.1"]}))
    assert [(x.field, x.value) for x in f] == [("params.O_deg", "missing")]
    f = check(_doc(_rec(MRCAL, theta=None)), parse_gate_spec({"limits": ["params.theta_deg:0"]}))
    assert f == []
    # only-ok statuses: not-applicable fails as well
    na = _rec(JPL, status="not-applicable", reason="camera 15 is a CAHVOR")
    f = check(_doc(na), parse_gate_spec({"statuses": ["ok"]}))
    assert [x.kind for x in f] == ["status"]


def test_status_regression_against_baseline():
    base = _doc(_rec(JPL))
    run = _doc(_rec(JPL, status="failed", reason="renderer error"))
    spec = parse_gate_spec({"statuses": ["ok", "failed", "not-applicable"],
                            "regressions": ["projection.rms:1%"]})
    f = check(run, spec, base)
    assert [(x.field, x.value, x.limit) for x in f] == [
        ("status", "failed: renderer error", "ok (as in baseline)")]


def test_regressions_without_baseline_are_a_usage_error():
    with pytest.raises(GateUsageError, match="no baseline was given; pass --baseline FILE"):
        check(_doc(_rec(JPL)), SPEC, None)


@pytest.mark.parametrize("doc, message", [
    ({"limts": []}, "limts: unknown key"),
    ({"limits": ["projection.rms:5%"]}, "a limit against the truth is absolute"),
    ({"limit": [{"field": "x"}]}, r"limit\[0\]: needs field"),
    ({"limit": [{"field": "x", "max": 1, "where": "*"}]}, r"limit\[0\]\.where: unknown key"),
    ({"statuses": ["fine"]}, "statuses: expected a list from ok, failed, not-applicable"),
    ({"regression": [{"field": "x", "tolerance": "lots"}]}, "tolerance 'lots'"),
])
def test_bad_specs(doc, message):
    with pytest.raises(GateUsageError, match=message):
        parse_gate_spec(doc)


def test_shipped_gate_spec_parses():
    spec = load_gate_spec(ROOT / "campaigns" / "gate.toml")
    assert spec.limits and not spec.needs_baseline
    reg = load_gate_spec(ROOT / "campaigns" / "gate-regression.toml")
    assert reg.needs_baseline


def _cli(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "camval.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=120)


def _store(path, *records):
    store = RunStore.create(path, {"name": "t"})
    for r in records:
        store.save_job(r["fullname"].rsplit("/", 1)[0] + r["calibrator"], [r])
    store.assemble()
    return path


def test_cli_gate_and_baseline(tmp_path):
    good = _store(tmp_path / "good", _rec(JPL), _rec(MRCAL, theta=None))
    bad = _store(tmp_path / "bad", _rec(JPL, proj=0.01), _rec(MRCAL, theta=None))
    spec = tmp_path / "spec.toml"
    spec.write_text('limits = ["projection.rms:0.002"]\nregressions = ["projection.rms:10%"]\n')
    # baseline: written once, never overwritten
    base = tmp_path / "base.json"
    out = _cli("baseline", "save", good, "-o", base)
    assert out.returncode == 0, out.stderr
    assert json.loads(base.read_text())["kind"] == "camval-baseline"
    before = base.read_bytes()
    out = _cli("baseline", "save", bad, "-o", base)
    assert out.returncode == 2 and "already exists" in out.stderr
    assert base.read_bytes() == before
    # pass
    out = _cli("gate", good, "--spec", spec, "--baseline", base)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "passed: 2 records" in out.stdout
    # fail: one table naming fullname, field, value, limit; exit 1
    out = _cli("gate", bad, "--spec", spec, "--baseline", base)
    assert out.returncode == 1
    assert out.stdout.count(JPL) == 2 and "FAILED: 2 failure(s)" in out.stdout
    # usage errors: exit 2 in one line
    out = _cli("gate", good, "--spec", spec)
    assert out.returncode == 2 and "no baseline was given" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    out = _cli("gate", tmp_path / "nope", "--spec", spec, "--baseline", base)
    assert out.returncode == 2 and "nope' does not exist" in out.stderr

r'''The gate's [[scatter]] limits (thresholds read from each record), the renderer spec
and the minimum detectable fault'''

from pathlib import Path

import pytest

from harness.gate import (
    GateUsageError,
    check,
    explain,
    load_gate_spec,
    minimum_detectable_faults,
    parse_gate_spec,
)

ROOT = Path(__file__).resolve().parents[1]
NAME = "15/CAHVOR/dots/raycast[spp=16,adaptive]/jpl[CAHVOR]"


def _rec(hc, sigma_hc=0.001, rms=2e-4, sigma_rms=4e-4, far=False, name=NAME):
    return {"fullname": name, "camera": "15", "status": "ok", "calibrator": "jpl",
            "verdict": {"floor_far": far,
                        "renderer": {"params": {"Hc": hc, "theta_deg": None},
                                     "projection": {"rms": rms},
                                     "sigma": {"Hc": sigma_hc, "projection_rms": sigma_rms,
                                               "Hs": 5e-7}}}}


SPEC = {"scatter": [
    {"field": "verdict.renderer.params.Hc", "sigma": "verdict.renderer.sigma.Hc", "z": 5,
     "floor": 1e-4},
    {"field": "verdict.renderer.params.theta_deg", "sigma": "verdict.renderer.sigma.theta_deg",
     "z": 5},
    {"field": "verdict.renderer.projection.rms", "sigma": "verdict.renderer.sigma.projection_rms",
     "z": 5, "floor": 1e-4, "cap": 0.005}]}


def test_scatter_limits_read_sigma_from_the_record():
    spec = parse_gate_spec(SPEC)
    assert check({"records": {NAME: _rec(0.004)}}, spec) == []         # z 4
    (f,) = check({"records": {NAME: _rec(0.006)}}, spec)               # z 6
    assert f.field == "verdict.renderer.params.Hc" and f.kind == "scatter"
    assert f.value == "0.006 (sigma 0.001, z 6)"
    assert f.limit.startswith("<= 0.005 (5 sigma")
    # the same difference passes where the record's own scatter is larger
    assert check({"records": {NAME: _rec(0.006, sigma_hc=0.002)}}, spec) == []
    # floor: a tiny sigma does not make a tiny difference fail
    assert check({"records": {NAME: _rec(5e-5, sigma_hc=1e-6)}}, spec) == []
    # cap: a huge sigma does not let a large projection difference pass
    (f,) = check({"records": {NAME: _rec(0.0, rms=0.006, sigma_rms=0.01)}}, spec)
    assert "cap" in f.limit and "z 0.6" in f.value


def test_far_floor_records_are_not_judged_unless_asked():
    recs = {"records": {NAME: _rec(0.05, far=True)}}
    assert check(recs, parse_gate_spec(SPEC)) == []
    assert len(check(recs, parse_gate_spec(dict(SPEC, judge_far_floor=True)))) == 1


@pytest.mark.parametrize("doc, message", [
    ({"scatter": [{"field": "x", "z": 3}]}, "needs field"),
    ({"scatter": [{"field": "x", "sigma": "y", "z": 3, "k": 1}]}, r"scatter\[0\]\.k: unknown"),
    ({"scatter": [{"field": "x", "sigma": "y", "z": -3}]}, "non-negative"),
    ({"judge_far_floor": "yes"}, "true or false"),
])
def test_bad_scatter_specs(doc, message):
    with pytest.raises(GateUsageError, match=message):
        parse_gate_spec(doc)


def test_renderer_spec_and_minimum_detectable_faults():
    spec = load_gate_spec(ROOT / "campaigns" / "gate-renderer.toml")
    assert spec.scatter and not spec.needs_baseline
    run = {"records": {NAME: _rec(0.0), "15/x/mrcal[CAHVOR]": _rec(0.0, sigma_hc=0.1,
                                                                      name="15/x/mrcal")}}
    mdf = minimum_detectable_faults(run, spec)
    hc = mdf["15"]["Hc shift"]
    assert hc["value"] == pytest.approx(0.006) and hc["record"] == NAME   # 6 x 0.001 px
    assert mdf["15"]["focal scale"]["value"] == pytest.approx(3e-6)
    text = "\n".join(explain(run, spec))
    assert "camera 15:" in text and "Hc shift" in text and "theta change  not judged" in text


def test_run_document_and_report_carry_the_minimum_detectable_faults(tmp_path):
    from harness.records import RunStore
    from reports.tables import detectable_fault_rows
    store = RunStore.create(tmp_path / "run", {"name": "t"})
    store.save_job("j", [_rec(0.0)])
    doc = store.assemble()
    assert doc["minimum_detectable_faults"]["cameras"]["15"]["Hc shift"]["value"] == \
        pytest.approx(0.006)
    (row,) = detectable_fault_rows(doc)
    assert row[:2] == ("15", "0.006") and row[4] == "—"


def test_records_whose_fits_disagree_are_not_judged():
    r = _rec(0.05)
    r["verdict"]["fits_disagree"] = True
    assert check({"records": {NAME: r}}, parse_gate_spec(SPEC)) == []

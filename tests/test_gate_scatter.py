r'''The gate's [[scatter]] limits (thresholds read from each record), the renderer spec
and the minimum detectable fault'''

import math
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
    # cap: a sigma whose z bound lies above it does not let a larger projection difference
    # pass (6 x 0.00125 = 0.0075 > cap 0.005 >= 4 x 0.00125)
    (f,) = check({"records": {NAME: _rec(0.0, rms=0.006, sigma_rms=0.00125)}}, spec)
    assert "(cap;" in f.limit and "z 4.8" in f.value
    # ... but it is never held below CAP_MIN_Z sigma, which a perfect renderer would fail by
    # chance (a 160x120 camera's mrcal sigma 0.01 px against a 0.02 px cap), where that
    # sigma comes from detection noise (detected - exact no larger than the residual noise)
    def noisy(rms, detected_minus_exact):
        r = _rec(0.0, rms=rms, sigma_rms=0.01)
        r["verdict"]["detection_noise"] = {"rms": detected_minus_exact}
        r["verdict"]["scatter"] = {"noise_per_pose": [0.012, None, 0.014]}
        return {"records": {NAME: r}}
    assert check(noisy(0.006, 0.013), spec) == []
    (f,) = check(noisy(0.041, 0.013), spec)
    assert "cap raised to 4 sigma" in f.limit and "z 4.1" in f.value
    # a fault the fit absorbed (detected - exact far above the residual noise: a flipped
    # image fitted as a board seen from behind) keeps the cap
    (f,) = check(noisy(0.006, 5.0), spec)
    assert "(cap;" in f.limit


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


def test_minimum_detectable_fault_leaves_out_records_that_measured_no_noise():
    # a corner target on the reference render: its detections ARE the exact observations,
    # so its detection noise and sigmas are 0; the camera's figure comes from the dots
    spec = load_gate_spec(ROOT / "campaigns" / "gate-renderer.toml")
    own = _rec(0.0, sigma_hc=0.0, name="15/x/apriltag/jpl[CAHVOR]")
    own["verdict"]["detection_noise"] = {"rms": 0.0}
    dots = _rec(0.0)
    dots["verdict"]["detection_noise"] = {"rms": 7e-5}
    mdf = minimum_detectable_faults({"records": {"15/x/apriltag/jpl[CAHVOR]": own,
                                                 NAME: dots}}, spec)
    assert mdf["15"]["Hc shift"]["record"] == NAME
    assert mdf["15"]["Hc shift"]["value"] == pytest.approx(0.006)     # 6 x 0.001 px
    assert minimum_detectable_faults({"records": {"a": own}}, spec) == {}


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


def test_report_has_a_column_for_the_roll_about_A():
    # jpl's world-frame fits report roll_deg (the turn of H' about A); the renderer gate sees
    # a roll through the joint test only: its figure is sqrt(chi2 limit) x fault_sigma
    from harness.verdict import joint_limit
    from reports.build import _html_table
    from reports.tables import DETECTABLE_HEADER, detectable_fault_rows
    spec = load_gate_spec(ROOT / "campaigns" / "gate-renderer.toml")
    (jl,) = [j for j in spec.joint if j.field == "verdict.renderer.joint"]
    r = _rec(0.0)
    r["verdict"]["renderer"]["sigma"]["roll_deg"] = 1e-3     # marginal: no [[scatter]] on it
    r["verdict"]["renderer"]["joint"] = {"chi2": 3.0, "dof": 14, "z": 0.4,
                                         "fault_sigma": {"roll_deg": 2e-4}}
    mdf = minimum_detectable_faults({"records": {NAME: r}}, spec)
    roll = mdf["15"]["roll about A"]
    assert roll["unit"] == "deg" and roll["record"] == NAME
    assert roll["value"] == pytest.approx(math.sqrt(joint_limit(jl.z, 14)) * 2e-4, rel=1e-9)
    assert DETECTABLE_HEADER[-1] == "roll about A deg" and len(DETECTABLE_HEADER) == 7
    doc = {"minimum_detectable_faults": {"cameras": mdf}}
    (row,) = detectable_fault_rows(doc)
    assert len(row) == len(DETECTABLE_HEADER)
    assert row[0] == "15" and float(row[-1]) == pytest.approx(roll["value"], rel=1e-2)
    assert row[4] == "—"    # theta: not judged on this record
    # the report's table (reports.build) shows the column with the figure
    html = _html_table(DETECTABLE_HEADER, [row])
    assert "<th>roll about A deg</th>" in html and f"<td class=\"num\">{row[-1]}</td>" in html


def test_records_whose_fits_disagree_are_not_judged():
    r = _rec(0.05)
    r["verdict"]["fits_disagree"] = True
    assert check({"records": {NAME: r}}, parse_gate_spec(SPEC)) == []


def _joint(chi2, dof=14, fault_sigma=None):
    r = _rec(0.0)
    r["verdict"]["renderer"]["joint"] = {
        "chi2": chi2, "dof": dof, "z": None if chi2 is None else float(math.sqrt(chi2)),
        "fault_sigma": fault_sigma or {}}
    return r


JOINT = {"joint": [{"field": "verdict.renderer.joint", "z": 6, "match": "*/jpl[*]"}]}


def test_joint_limit_is_the_chi_square_quantile_of_the_gaussian_tail_at_z():
    from scipy import stats
    spec = parse_gate_spec(JOINT)
    lim = stats.chi2.isf(2 * stats.norm.sf(6), 14)      # 69.9: p 1.97e-9, as z 6 alone
    assert check({"records": {NAME: _joint(0.99 * lim)}}, spec) == []
    (f,) = check({"records": {NAME: _joint(1.01 * lim)}}, spec)
    # the failure line says the quantity, its value with its dof, and the limit
    assert f.field == "verdict.renderer.joint.chi2" and f.kind == "joint"
    assert f.value.startswith(f"{1.01 * lim:.6g} (dof 14, z ")
    assert f.limit.startswith(f"<= {lim:.4g} (chi-square dof 14 at p 1.97e-09 = 6 sigma")
    # dof 1: the limit is z^2
    (f,) = check({"records": {NAME: _joint(36.5, dof=1)}}, spec)
    assert f.limit.startswith("<= 36 (")
    assert check({"records": {NAME: _joint(35.5, dof=1)}}, spec) == []
    # nothing the fit determines: nothing to judge; a far floor: not judged
    assert check({"records": {NAME: _joint(None, dof=0)}}, spec) == []
    far = _joint(1e4)
    far["verdict"]["floor_far"] = True
    assert check({"records": {NAME: far}}, spec) == []
    # a fit without covariance has no joint table (its sigmas are absent too): not judged;
    # a record without the renderer verdict is missing it
    assert check({"records": {NAME: _rec(0.0)}}, spec) == []
    bare = {k: v for k, v in _rec(0.0).items() if k != "verdict"}
    (f,) = check({"records": {NAME: bare}}, spec)
    assert f.kind == "missing"
    # other calibrators are not matched by this entry
    fails = check({"records": {NAME: _joint(1e4), "15/x/mrcal[CAHVOR]": _joint(1e4)}}, spec)
    assert [f.fullname for f in fails] == [NAME]
    # an entry matching no record fails, unless it is optional (a CAHVORE-only run)
    other = {"records": {"15/x/mrcal[CAHVOR]": _joint(1e4)}}
    (f,) = check(other, spec)
    assert f.kind == "unmatched"
    optional = {"joint": [dict(JOINT["joint"][0], optional=True)]}
    assert check(other, parse_gate_spec(optional)) == []


@pytest.mark.parametrize("doc, message", [
    ({"joint": [{"z": 6}]}, "needs field"),
    ({"joint": [{"field": "x", "z": 6, "sigma": "y"}]}, r"joint\[0\]\.sigma: unknown"),
    ({"joint": [{"field": "x", "z": 0}]}, "positive"),
    ({"joint": {"field": "x"}}, r"\[\[joint\]\] tables"),
    ({"joint": [{"field": "x", "z": 6, "optional": "yes"}]}, "true or false"),
])
def test_bad_joint_specs(doc, message):
    with pytest.raises(GateUsageError, match=message):
        parse_gate_spec(doc)


def test_minimum_detectable_fault_takes_the_joint_test_where_it_sees_further():
    from scipy import stats
    spec = load_gate_spec(ROOT / "campaigns" / "gate-renderer.toml")
    assert any(j.field == "verdict.renderer.joint" and j.z == 6 for j in spec.joint)
    lim = stats.chi2.isf(2 * stats.norm.sf(6), 14)
    # Hc's marginal sigma 0.001 px (limit 0.006 px); the joint test sees an Hc shift by
    # 2e-5 px (A held: the noise moves Hc with A, the fault does not): sqrt(69.9) x 2e-5
    run = {"records": {NAME: _joint(3.0, fault_sigma={"Hc": 2e-5, "R1_frac": 1.0})}}
    mdf = minimum_detectable_faults(run, spec)["15"]
    assert mdf["Hc shift"]["value"] == pytest.approx(math.sqrt(lim) * 2e-5, rel=1e-9)
    assert "joint" in mdf["Hc shift"]["limit"]
    # where the marginal limit is smaller it stays (focal scale: 6 x 5e-7; R1: 6 x 1.0 > ...)
    assert mdf["focal scale"]["value"] == pytest.approx(3e-6)
    text = "\n".join(explain(run, spec))
    assert "verdict.renderer.joint.chi2 <= the chi-square(dof) quantile at 6 sigma" in text


def test_clean_statistics_counts_twin_cameras_once_and_reports_the_largest_z():
    # benchmarks/renderer_gate.py's summary of clean runs: z = |value| / sigma per judged
    # quantity; twin cameras (the same images: equal detection noise) are one test
    import importlib.util
    spec_file = importlib.util.spec_from_file_location(
        "renderer_gate", ROOT / "benchmarks" / "renderer_gate.py")
    rg = importlib.util.module_from_spec(spec_file)
    spec_file.loader.exec_module(rg)

    def rec(camera, hc, noise_max, far=False):
        r = _rec(hc, far=far, name=f"{camera}/CAHVOR/dots/raycast[spp=16]/jpl[CAHVOR]")
        r.update(camera=camera, model="CAHVOR", calibrator_model="CAHVOR")
        r["verdict"]["detection_noise"] = {"max": noise_max}
        return r
    recs = {r["fullname"]: r for r in (rec("13", 0.003, 1.5e-3), rec("14", 0.003, 1.5e-3),
                                        rec("15", -0.002, 2.5e-3), rec("16", 0.5, 3e-3, True))}
    lines, doc = rg.clean_statistics([(0, {"records": recs})], parse_gate_spec(SPEC))
    g = doc["jpl[CAHVOR]"]
    # 13 and 14 are twins (one record kept), 16's floor is far (not judged)
    assert g["records"] == 3 and g["judged"] == 2 and g["floor_far"] == 1
    # per judged record: Hc (sigma 0.001) and the projection RMS (2e-4 / 4e-4); theta is None
    assert g["marginal_tests"] == 4
    assert g["max_z"] == pytest.approx(3.0) and "Hc" in g["max_z_at"]
    assert g["rms_z"] == pytest.approx(math.sqrt((9 + 4 + 2 * 0.25) / 4))
    assert g["z_over_4"] == 0
    # the two-sided Gaussian tail at z 5 (the spec's), times the 4 tests
    assert "expected exceedances by chance 2.3e-06" in lines[-1]

'''Gate globs: fullnames carry brackets, and a limit that selects nothing is a failure'''

from pathlib import Path

from harness.gate import check, load_gate_spec

ROOT = Path(__file__).resolve().parents[1]


def _run(rms):
    name = "15/CAHVOR/dots/raycast[spp=16,adaptive]/jpl[CAHVOR]"
    rec = {"fullname": name, "status": "ok", "residuals": {"rms": rms, "max": rms},
           "projection": {"rms": rms, "max": rms},
           "params": {"Hc": 0.0, "Vc": 0.0, "theta_deg": 0.0, "C_mm": 0.0, "A_deg": 0.0}}
    return {"records": {name: rec}}


def test_default_gate_spec_applies_its_jpl_limits():
    spec = load_gate_spec(ROOT / "campaigns" / "gate.toml")
    assert check(_run(1e-4), spec) == []
    failures = check(_run(0.5), spec)
    fields = {f.field for f in failures}
    assert {"residuals.rms", "projection.rms"} <= fields
    assert all(f.fullname.endswith("/jpl[CAHVOR]") for f in failures)


def test_limit_matching_no_record_fails(tmp_path):
    spec_file = tmp_path / "g.toml"
    spec_file.write_text('[[limit]]\nfield = "residuals.rms"\nmax = 0.002\n'
                         'match = "*/colmap[*]"\n')
    failures = check(_run(1e-4), load_gate_spec(spec_file))
    assert len(failures) == 1
    assert failures[0].value == "matched no record"
    assert "colmap" in failures[0].limit

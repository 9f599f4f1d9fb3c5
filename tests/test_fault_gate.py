r'''examples/fault_renderer.py: its faults, the program through camval's protocol, and the
default renderer gate flagging its faults (slow: a campaign through the real program)

The full fault x camera x calibrator table is benchmarks/renderer_gate.py --external.
'''

import importlib.util
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from render_checks import board_pose, grid_board, small_model

REPO = Path(__file__).resolve().parents[1]
PROGRAM = REPO / "examples" / "fault_renderer.py"


def _program():
    spec = importlib.util.spec_from_file_location("fault_renderer", PROGRAM)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


fr = _program()


def _angle_deg(u, v):
    c = np.dot(u, v) / (np.linalg.norm(u) * np.linalg.norm(v))
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def test_each_fault_changes_its_parameter_by_its_stated_amount_and_nothing_else():
    m = small_model("CAHVORE")
    ph = m.photogrammetric()

    def ph_of(fault):
        return fr.faulty_model(m, fault).photogrammetric()
    assert ph_of("hc_shift").Hc - ph.Hc == pytest.approx(0.01, abs=1e-12)
    assert ph_of("hc_shift").Vc == pytest.approx(ph.Vc, abs=1e-12)
    assert ph_of("focal_scale").Hs / ph.Hs - 1 == pytest.approx(1e-5, rel=1e-6)
    assert ph_of("focal_scale").Vs / ph.Vs - 1 == pytest.approx(1e-5, rel=1e-6)
    t = small_model("CAHVOR", theta_deg=90.05)
    p90 = fr.faulty_model(t, "theta90").photogrammetric()
    assert p90.theta_deg == pytest.approx(90.0, abs=1e-10)
    assert (p90.Hc, p90.Hs) == pytest.approx((t.photogrammetric().Hc, t.photogrammetric().Hs))
    for fault, i in (("r1_scale", 1), ("r2_scale", 2)):
        R = fr.faulty_model(m, fault).R
        assert R[i] == pytest.approx(0.99 * m.R[i], rel=1e-14)
        assert np.array_equal(np.delete(R, i), np.delete(m.R, i))
    assert np.all(fr.faulty_model(m, "drop_e").E == 0) and np.any(m.E != 0)
    O2 = fr.faulty_model(m, "o_tilt").O
    # tilted away from A by the stated angle
    assert _angle_deg(m.O, O2) == pytest.approx(0.01, rel=1e-6)
    assert _angle_deg(m.A, O2) - _angle_deg(m.A, m.O) == pytest.approx(0.01, rel=1e-6)
    rc = ph_of("round_centre")
    assert (2 * rc.Hc, 2 * rc.Vc) == (round(2 * ph.Hc), round(2 * ph.Vc))
    hp = ph_of("half_pixel")
    assert (hp.Hc - ph.Hc, hp.Vc - ph.Vc) == pytest.approx((-0.5, -0.5), abs=1e-12)
    # O along A: the tilt still tilts (about H')
    a = m.replace(O=m.A)
    assert _angle_deg(a.A, fr.faulty_model(a, "o_tilt").O) == pytest.approx(0.01, rel=1e-6)


@pytest.mark.parametrize("fault, family", [("r1_scale", "CAHV"), ("r2_scale", "CAHV"),
                                           ("o_tilt", "CAHV"), ("drop_e", "CAHVOR")])
def test_a_fault_without_its_parameter_is_not_applicable(fault, family):
    with pytest.raises(fr.FaultNotApplicable, match=f"{fault}.*{family}"):
        fr.faulty_model(small_model(family), fault)


def test_an_unknown_fault_is_refused_with_the_known_ones():
    r = subprocess.run([sys.executable, str(PROGRAM), "--fault", "nope"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "hc_shift" in r.stderr and "'nope'" in r.stderr


def test_the_program_renders_the_faulty_camera_through_the_protocol(tmp_path):
    r'''One-shot, as camval runs it: the image is the exact ray caster's image of the
faulty model (to the 16-bit PNG's quantisation), and differs from the true camera's'''
    from renderers.base import RenderSettings
    from renderers.protocol import read_image, write_request
    from renderers.raycast import RaycastRenderer

    m = small_model("CAHVOR")
    (pattern, _), Rt = grid_board(), board_pose()
    s = RenderSettings(spp=2, adaptive=True)
    req = write_request(tmp_path, m, pattern, Rt, s)
    r = subprocess.run([sys.executable, str(PROGRAM), "--fault", "half_pixel", req],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    img = read_image(str(tmp_path / "image.png"), m.width, m.height)
    raycast = RaycastRenderer()
    want = raycast.render(fr.faulty_model(m, "half_pixel"), pattern, Rt, s).image
    true = raycast.render(m, pattern, Rt, s).image
    assert np.abs(img - want).max() <= 0.5 / 65535 + 1e-12
    assert np.abs(img - true).max() > 0.1       # a half-pixel shift moves the dot edges


@pytest.mark.slow
def test_the_default_gate_flags_the_programs_faults_and_passes_it_clean(tmp_path):
    r'''Rocky8 rear hazcam (17, CAHVOR, 640x480), jpl, 6 poses, K=16, through the real
program (persistent) as three labelled renderers: clean, Hc + 0.01 px and the centre
rounded to the half pixel. The gate is the default one (campaigns/gate-renderer.toml).'''
    from harness.campaign import parse_campaign
    from harness.gate import DEFAULT_SPEC, check, load_gate_spec
    from harness.runner import run_campaign

    faults = ("none", "hc_shift", "round_centre")
    doc = {"name": "fault-gate", "cameras": [17], "models": ["CAHVOR"], "targets": ["dots"],
           "poses": {"n": 6, "seed": 0}, "calibrator": [{"name": "jpl"}],
           "renderer": [{"name": "command", "label": f"fault-{f}", "spp": 16,
                         "setup": {"command": [sys.executable, str(PROGRAM), "--fault", f],
                                   "persistent": True}} for f in faults]}
    run = run_campaign(parse_campaign(doc), tmp_path / "run", progress=False, workers=1)
    failures = check(run, load_gate_spec(DEFAULT_SPEC))
    recs = {k.split("/")[3].split("[")[0].removeprefix("fault-"): r
            for k, r in run["records"].items()}
    assert set(recs) == set(faults) and all(r["status"] == "ok" for r in recs.values())
    assert all("fault_renderer.py" in r["versions"]["renderer"] for r in recs.values())
    failed = {}
    for f in failures:
        failed.setdefault(f.fullname.split("/")[3].split("[")[0].removeprefix("fault-"),
                          set()).add(f.field)
    assert "none" not in failed, failures
    ren = {k: r["verdict"]["renderer"] for k, r in recs.items()}
    # the shift moves the image fit's Hc by 0.01 px against the exact fit (to first order,
    # nothing else); 5 sigma of the record's own scatter around it
    assert "verdict.renderer.params.Hc" in failed["hc_shift"]
    hc = ren["hc_shift"]
    assert abs(hc["params"]["Hc"] - 0.01) < 5 * hc["sigma"]["Hc"]
    # rounding moves Hc and Vc to the nearest half pixel (camera 17: by -0.20 and -0.16 px)
    assert {"verdict.renderer.params.Hc", "verdict.renderer.params.Vc"} <= \
        failed["round_centre"]
    from reference_models.cahvore import truncate
    from reference_models.catalogue import load_catalogue
    ph = truncate(load_catalogue().get("17").model, "CAHVOR").photogrammetric()
    rc = ren["round_centre"]
    for p, v in (("Hc", ph.Hc), ("Vc", ph.Vc)):
        assert abs(rc["params"][p] - (round(2 * v) / 2 - v)) < 5 * rc["sigma"][p]

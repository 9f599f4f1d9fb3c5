r'''The gate on records of unseen cameras: the solver's stop (harness.gate.solver_stop) and
the new faults of benchmarks/renderer_gate.py (NEW_FAULT_DEFAULTS, world_pose)'''

import sys
from pathlib import Path

import numpy as np
import pytest

from harness.gate import SOLVER_STOP_FACTOR, check, parse_gate_spec
from reference_models.jpl_files import read_model

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import renderer_gate as rg  # noqa: E402

NAME = "tele/CAHVOR/dots/raycast[spp=16,adaptive]/jpl[CAHVOR]"
SPEC = {"scatter": [
    {"field": "verdict.renderer.params.R1_frac", "sigma": "verdict.renderer.sigma.R1_frac",
     "z": 6}]}


def _rec(value, sigma, floor, fit_family="CAHVOR"):
    return {"fullname": NAME, "camera": "tele", "status": "ok", "calibrator": "jpl",
            "model": "CAHVOR", "calibrator_model": fit_family,
            "verdict": {"floor": {"params": {"R1_frac": floor}},
                        "renderer": {"params": {"R1_frac": value},
                                     "sigma": {"R1_frac": sigma}}}}


def test_the_solvers_stop_widens_the_limit_where_the_exact_fit_stopped_short():
    # the 2.5 deg telephoto's pose seed 5: R1_frac 1.0e-3 at sigma 1.34e-4 (z 7.5), its exact
    # fit 2.4e-4 off the truth: judged against sqrt(sigma^2 + 2 floor^2) = 3.6e-4, z 2.8
    spec = parse_gate_spec(SPEC)
    assert check({"records": {NAME: _rec(1.0e-3, 1.34e-4, 0.0)}}, spec)
    assert check({"records": {NAME: _rec(1.0e-3, 1.34e-4, 2.38e-4)}}, spec) == []
    # a difference beyond 6 x the combined sigma still fails, and says the stop
    (f,) = check({"records": {NAME: _rec(3e-3, 1.34e-4, 2.38e-4)}}, spec)
    assert "solver's stop" in f.value
    s = np.hypot(1.34e-4, SOLVER_STOP_FACTOR * 2.38e-4)
    assert f.value.endswith(f"z {3e-3 / s:.3g})")
    # a fit of another family: its floor is the misfit, which cancels: no widening
    assert check({"records": {NAME: _rec(1.0e-3, 1.34e-4, 2.38e-4, "CAHV")}}, spec)


@pytest.mark.parametrize("fault", ["roll", "c_along_a"])
def test_extrinsic_faults_keep_the_board_in_the_world(fault):
    # rendered in its own camera frame, a rolled or moved camera would make the true
    # camera's images; world_pose keeps the board where the true frame puts it
    model = read_model(ROOT / "campaigns" / "cameras" / "aspect-1000x800.cahvor")
    fr = rg.fault_program()
    bad = fr.faulty_model(model, fault)
    Rt = np.vstack((np.eye(3), [0.1, -0.2, 2.0]))
    Rt2 = rg.world_pose(model, bad, Rt)
    p_board = np.array([[0.0, 0.0, 0.0], [0.5, 0.3, 0.0]])

    def world(m, Rt):
        T = m.Rt_ref_cam()
        return (p_board @ Rt[:3].T + Rt[3]) @ T[:3].T + T[3]
    assert np.allclose(world(model, Rt), world(bad, Rt2), atol=1e-12)
    # and the image change there is what the fault's size says (0.0064 px for a 0.001 deg
    # roll, 0.02 px for 0.1 mm along A on this 1000x800 camera at 2 m)
    assert rg.world_fault_size(model, bad) > 1e-3


def test_intrinsic_faults_leave_the_pose_alone():
    model = read_model(ROOT / "campaigns" / "cameras" / "aspect-1000x800.cahvor")
    fr = rg.fault_program()
    Rt = np.vstack((np.eye(3), [0.1, -0.2, 2.0]))
    for fault in ("vs_scale", "vc_shift", "flip_y"):
        assert np.allclose(rg.world_pose(model, fr.faulty_model(model, fault), Rt), Rt,
                           atol=1e-12)
